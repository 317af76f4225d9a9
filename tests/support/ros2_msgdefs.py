"""ROS 2 message definitions as ``<dir>/<package>/msg/<Name>.msg`` files, written from the definitions rosbags
ships (its Jazzy typestore), for clients that read .msg files and would otherwise fetch them from git at run
time (zenoh-ros2-sdk's ``get_registry(messages_dir)``): the tests stay offline."""

from __future__ import annotations

from pathlib import Path

SEPARATOR = "\n" + "=" * 80 + "\n"  # between a definition and its dependencies' in generate_msgdef's text


def write_msgdefs(directory: Path) -> Path:
    """Every message of rosbags' ROS 2 Jazzy store as its own .msg file (the type's own part of the
    definition rosbags generates, dependencies left to their own files); ``directory``."""
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    for name in store.fielddefs:
        package, kind, msg = name.split("/")
        path = directory / package / kind / f"{msg}.msg"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(store.generate_msgdef(name, ros_version=2)[0].split(SEPARATOR)[0])
    return directory


def offline_sdk_registry(directory: Path) -> None:
    """zenoh-ros2-sdk's global message registry, new, reading the definitions written to ``directory``: call it
    before any SDK session. New each time: the SDK's registry remembers the types it loaded into a session's
    store, so a second test's session (a new store) would otherwise miss them."""
    from zenoh_ros2_sdk import message_registry
    message_registry._registry = None
    message_registry.get_registry(str(write_msgdefs(directory)))
