"""The wire: every message kind (schema, codec, field checks), key expressions, the checks after the schema and the messages built from the world's and agents' arrays. Pure: no Zenoh, no I/O."""
