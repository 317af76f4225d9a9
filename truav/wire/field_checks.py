"""Field checks of the wire schema: each is ``(field path, value) -> normalised value`` or raises
:class:`~truav.wire.schema_names.SchemaError`; the message classes (:mod:`truav.wire.messages`) name one
per field."""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from math import isfinite
from typing import Any

import numpy as np

from truav.wire.keys import MAX_UAVS
from truav.wire.schema_names import (INT64_MAX, MAX_ARGS_DEPTH, MAX_ARGS_NODES, MAX_ARGS_STR_LEN,
                                    MAX_BEACON_FIELD_NAME, MAX_BEACON_FIELDS, MAX_NAME_LEN, MAX_PARAM_STR_LEN, MAX_SMALL_PAYLOAD_BYTES, MAX_SRC_LEN, R_BAD_TYPE, R_OUT_OF_RANGE,
                                    UINT64_MAX, _NAME_RE, _SRC_RE, SchemaError)
from truav.actions import HOVER, N_ACTIONS

# --- field checks: (field path, value) -> normalised value, or SchemaError --------
Check = Callable[[str, Any], Any]

# A check may carry ``FAST``: a description of its common case, which the decoder (truav.wire.codec) inlines
# and on which the check returns its value unchanged: ("int", lo, hi) a plain int in [lo, hi]; ("real", lo,
# lo_open) a finite plain float in range; ("bool",) a plain bool; ("text",) a str the check accepted before
# (remembered, bounded); ("choice", options) a str among options; ("vec2",) a list or tuple of two finite
# plain floats (returned as a tuple). Anything else, and any value off the common case, goes through the check
# itself, which then says what is wrong exactly as it always did.

_INT_TYPES = (int, np.integer)
_REAL_TYPES = (int, float, np.integer, np.floating)
_BOOL_TYPES = (bool, np.bool_)


def _int(lo: int, hi: int) -> Check:
    """An int in ``[lo, hi]`` (bools rejected)."""

    def check(name: str, v: Any) -> int:
        if type(v) is int and lo <= v <= hi:  # the common case first: a plain int (never a bool) in range
            return v
        if isinstance(v, _BOOL_TYPES) or not isinstance(v, _INT_TYPES):
            raise SchemaError(R_BAD_TYPE, f"{name} must be an int, got {type(v).__name__}")
        v = int(v)
        if not lo <= v <= hi:
            raise SchemaError(R_OUT_OF_RANGE, f"{name}={v} outside [{lo}, {hi}]")
        return v

    check.FAST = ("int", lo, hi)  # type: ignore[attr-defined]
    return check


def _real(lo: float | None = None, *, lo_open: bool = False) -> Check:
    """A finite float (ints accepted), optionally ``>= lo`` (``> lo`` if lo_open)."""

    def check(name: str, v: Any) -> float:
        if type(v) is float and isfinite(v) and (lo is None or (v > lo if lo_open else v >= lo)):  # common case
            return v
        if isinstance(v, _BOOL_TYPES) or not isinstance(v, _REAL_TYPES):
            raise SchemaError(R_BAD_TYPE, f"{name} must be a number, got {type(v).__name__}")
        v = float(v)
        if not math.isfinite(v):
            raise SchemaError(R_OUT_OF_RANGE, f"{name}={v} is not finite")
        if lo is not None and (v <= lo if lo_open else v < lo):
            raise SchemaError(R_OUT_OF_RANGE, f"{name}={v} must be {'>' if lo_open else '>='} {lo}")
        return v

    check.FAST = ("real", lo, lo_open)  # type: ignore[attr-defined]
    return check


def _bool(name: str, v: Any) -> bool:
    if not isinstance(v, _BOOL_TYPES):
        raise SchemaError(R_BAD_TYPE, f"{name} must be a bool, got {type(v).__name__}")
    return bool(v)


_bool.FAST = ("bool",)  # type: ignore[attr-defined]


def _text(max_len: int, pattern: re.Pattern[str] | None = None, *, allow_empty: bool = False) -> Check:
    def check(name: str, v: Any) -> str:
        if not isinstance(v, str):
            raise SchemaError(R_BAD_TYPE, f"{name} must be a str, got {type(v).__name__}")
        if (not v and not allow_empty) or len(v) > max_len:
            raise SchemaError(R_OUT_OF_RANGE, f"{name} must have 1..{max_len} characters")
        if v and pattern is not None and not pattern.fullmatch(v):
            raise SchemaError(R_OUT_OF_RANGE, f"{name}={v[:max_len]!r} has invalid characters")
        return v

    check.FAST = ("text",)  # type: ignore[attr-defined]
    return check


def _choice(options: tuple[str, ...]) -> Check:
    def check(name: str, v: Any) -> str:
        if not isinstance(v, str):
            raise SchemaError(R_BAD_TYPE, f"{name} must be a str, got {type(v).__name__}")
        if v not in options:
            raise SchemaError(R_OUT_OF_RANGE, f"{name}={v[:32]!r} not one of {options}")
        return v

    check.FAST = ("choice", options)  # type: ignore[attr-defined]
    return check


_finite = _real()
_nonneg = _real(0.0)
_positive = _real(0.0, lo_open=True)
_uint63 = _int(0, INT64_MAX)
_uint64 = _int(0, UINT64_MAX)
_int64 = _int(-INT64_MAX - 1, INT64_MAX)
_uav_id = _int(0, MAX_UAVS - 1)
_n_uavs = _int(0, MAX_UAVS)
_action = _int(0, N_ACTIONS - 1)
_action_or_hover = _int(HOVER, N_ACTIONS - 1)
_sector = _int(0, 16)  # learner.sense_sectors is at most 16; 0 = none sensed
_name = _text(MAX_NAME_LEN, _NAME_RE)
_src = _text(MAX_SRC_LEN, _SRC_RE, allow_empty=True)


def _pad(name: str, v: Any) -> bytes:
    """Opaque padding bytes (the rest of a fixed-size report), at most a small payload."""
    if not isinstance(v, (bytes, bytearray)):
        raise SchemaError(R_BAD_TYPE, f"{name} must be bytes, got {type(v).__name__}")
    if len(v) > MAX_SMALL_PAYLOAD_BYTES:
        raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(v)} bytes, cap is {MAX_SMALL_PAYLOAD_BYTES}")
    return bytes(v)


def _vec2(name: str, v: Any) -> tuple[float, float]:
    if (type(v) is list or type(v) is tuple) and len(v) == 2:  # the common case: two finite floats
        x, y = v
        if type(x) is float and type(y) is float and isfinite(x) and isfinite(y):
            return (x, y)
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        raise SchemaError(R_BAD_TYPE, f"{name} must be a pair of numbers")
    return (_finite(f"{name}[0]", v[0]), _finite(f"{name}[1]", v[1]))


_vec2.FAST = ("vec2",)  # type: ignore[attr-defined]


def _points(max_n: int) -> Check:
    """A list of (x, y) pairs, at most ``max_n``; numpy (n, 2) arrays accepted."""

    def check(name: str, v: Any) -> tuple[tuple[float, float], ...]:
        if isinstance(v, np.ndarray):
            if v.ndim != 2 or (v.size and v.shape[1] != 2) or v.dtype.kind not in "iuf":
                raise SchemaError(R_BAD_TYPE, f"{name} must be an (n, 2) numeric array")
            if len(v) > max_n:
                raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(v)} points, cap is {max_n}")
            if not np.isfinite(v).all():
                raise SchemaError(R_OUT_OF_RANGE, f"{name} has non-finite coordinates")
            return tuple((float(x), float(y)) for x, y in v.reshape(-1, 2).tolist())
        if not isinstance(v, (list, tuple)):
            raise SchemaError(R_BAD_TYPE, f"{name} must be a list of [x, y]")
        if len(v) > max_n:
            raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(v)} points, cap is {max_n}")
        return tuple(_vec2(f"{name}[{k}]", p) for k, p in enumerate(v))

    return check


def _ints(max_n: int, lo: int, hi: int) -> Check:
    """A list of at most ``max_n`` ints, each in ``[lo, hi]``; numpy integer arrays accepted (a numpy int64 array
    out: federated Q shares carry hundreds)."""

    def check(name: str, v: Any) -> np.ndarray:
        if isinstance(v, np.ndarray) and v.ndim == 1 and v.dtype.kind in "iu":
            arr = v.astype(np.int64)
        elif isinstance(v, (list, tuple)) and all(type(x) is int for x in v):
            if any(not -(1 << 63) <= x <= INT64_MAX for x in v):
                raise SchemaError(R_OUT_OF_RANGE, f"{name} has values outside [{lo}, {hi}]")
            arr = np.array(v, np.int64)
        else:
            raise SchemaError(R_BAD_TYPE, f"{name} must be a list of ints")
        if len(arr) > max_n:
            raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(arr)} values, cap is {max_n}")
        if len(arr) and (arr.min() < lo or arr.max() > hi):
            raise SchemaError(R_OUT_OF_RANGE, f"{name} has values outside [{lo}, {hi}]")
        return arr

    return check


def _floats(max_n: int) -> Check:
    """A list of at most ``max_n`` finite float64 (ints accepted); numpy float arrays accepted (a numpy float64
    array out)."""

    def check(name: str, v: Any) -> np.ndarray:
        if isinstance(v, np.ndarray) and v.ndim == 1 and v.dtype.kind in "iuf":
            arr = v.astype(np.float64)
        elif isinstance(v, (list, tuple)) and all(type(x) is float or type(x) is int for x in v):
            try:
                arr = np.array(v, np.float64)
            except OverflowError:
                raise SchemaError(R_OUT_OF_RANGE, f"{name} has values outside float64") from None
        else:
            raise SchemaError(R_BAD_TYPE, f"{name} must be a list of numbers")
        if len(arr) > max_n:
            raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(arr)} values, cap is {max_n}")
        if not np.isfinite(arr).all():
            raise SchemaError(R_OUT_OF_RANGE, f"{name} has non-finite values")
        return arr

    return check


def _str_map(max_entries: int, value_check: Check) -> Check:
    """A map of names to checked values, at most ``max_entries``."""

    def check(name: str, v: Any) -> dict[str, Any]:
        if not isinstance(v, Mapping):
            raise SchemaError(R_BAD_TYPE, f"{name} must be a map")
        if len(v) > max_entries:
            raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(v)} entries, cap is {max_entries}")
        out: dict[str, Any] = {}
        for k, x in v.items():
            out[_name(f"{name} key", k)] = value_check(f"{name}[{k!r}]", x)
        return out

    return check


_param_text = _text(MAX_PARAM_STR_LEN, allow_empty=True)


_printable_src = _text(MAX_SRC_LEN, re.compile(r"[ -~]+"))  # a sender as a receiver names it: "?", "(other senders)"


_beacon_field_name = _text(MAX_BEACON_FIELD_NAME, re.compile(r"[ -~]+"))


def _beacon_field_value(name: str, v: Any) -> bool | int | float:
    if isinstance(v, _BOOL_TYPES):
        return bool(v)
    if isinstance(v, _INT_TYPES):
        return _int64(name, v)
    if isinstance(v, (float, np.floating)):
        return _finite(name, v)
    raise SchemaError(R_BAD_TYPE, f"{name} must be a bool, int or float, got {type(v).__name__}")


def _beacon_fields(name: str, v: Any) -> dict[str, bool | int | float]:
    """A beacon's extra fields: at most MAX_BEACON_FIELDS, printable names of 1-MAX_BEACON_FIELD_NAME
    characters, values bool, int64 or finite float."""
    if not isinstance(v, Mapping):
        raise SchemaError(R_BAD_TYPE, f"{name} must be a map")
    if len(v) > MAX_BEACON_FIELDS:
        raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(v)} entries, cap is {MAX_BEACON_FIELDS}")
    return {_beacon_field_name(f"{name} key", k): _beacon_field_value(f"{name}[{k!r}]", x) for k, x in v.items()}


def _count_map(max_entries: int, key_check: Check) -> Check:
    """A map of checked keys to counts (ints >= 0), at most ``max_entries``."""

    def check(name: str, v: Any) -> dict[str, int]:
        if not isinstance(v, Mapping):
            raise SchemaError(R_BAD_TYPE, f"{name} must be a map")
        if len(v) > max_entries:
            raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(v)} entries, cap is {max_entries}")
        return {key_check(f"{name} key", k): _uint63(f"{name}[{k!r}]", x) for k, x in v.items()}

    return check


def _counts(max_n: int) -> Check:
    """A list of at most ``max_n`` counts (ints in [0, 2^63-1]), as a tuple; numpy integer arrays accepted."""

    def check(name: str, v: Any) -> tuple[int, ...]:
        if isinstance(v, np.ndarray) and v.ndim == 1 and v.dtype.kind in "iu":
            v = v.tolist()
        if not isinstance(v, (list, tuple)):
            raise SchemaError(R_BAD_TYPE, f"{name} must be a list of counts")
        if len(v) > max_n:
            raise SchemaError(R_OUT_OF_RANGE, f"{name} has {len(v)} values, cap is {max_n}")
        return tuple(_uint63(f"{name}[{k}]", x) for k, x in enumerate(v))

    return check


def _param_value(name: str, v: Any) -> float | int | str:
    if isinstance(v, str):
        return _param_text(name, v)
    if isinstance(v, _INT_TYPES) and not isinstance(v, _BOOL_TYPES):
        return _int64(name, v)
    if isinstance(v, (float, np.floating)):
        return _finite(name, v)
    raise SchemaError(R_BAD_TYPE, f"{name} must be a float, int or str, got {type(v).__name__}")


def _json_like(name: str, v: Any) -> dict[str, Any]:
    """Control ``args``: a map of JSON-like values (None, bool, int, float, str, list, map)."""
    budget = [MAX_ARGS_NODES]

    def walk(path: str, x: Any, depth: int) -> Any:
        budget[0] -= 1
        if budget[0] < 0:
            raise SchemaError(R_OUT_OF_RANGE, f"{name} has more than {MAX_ARGS_NODES} values")
        if depth > MAX_ARGS_DEPTH:
            raise SchemaError(R_OUT_OF_RANGE, f"{path} nests deeper than {MAX_ARGS_DEPTH}")
        if x is None or isinstance(x, bool):
            return x
        if isinstance(x, np.bool_):
            return bool(x)
        if isinstance(x, _INT_TYPES):
            return _int64(path, x)
        if isinstance(x, (float, np.floating)):
            return _finite(path, x)
        if isinstance(x, str):
            if len(x) > MAX_ARGS_STR_LEN:
                raise SchemaError(R_OUT_OF_RANGE, f"{path} is longer than {MAX_ARGS_STR_LEN}")
            return x
        if isinstance(x, (list, tuple)):
            return [walk(f"{path}[{k}]", y, depth + 1) for k, y in enumerate(x)]
        if isinstance(x, Mapping):
            out = {}
            for k, y in x.items():
                if not isinstance(k, str) or len(k) > MAX_NAME_LEN:
                    raise SchemaError(R_BAD_TYPE, f"{path} keys must be str of <= {MAX_NAME_LEN} chars")
                out[k] = walk(f"{path}.{k}", y, depth + 1)
            return out
        raise SchemaError(R_BAD_TYPE, f"{path} has unsupported type {type(x).__name__}")

    if not isinstance(v, Mapping):
        raise SchemaError(R_BAD_TYPE, f"{name} must be a map")
    return walk(name, v, 0)

