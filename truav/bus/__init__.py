"""The bus: message schema, key expressions, the Zenoh transport and the beacon inbox."""
