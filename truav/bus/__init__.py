"""The bus: Zenoh sessions, publishing and receiving, the router, access control and certificates, the link filter (the messages themselves are truav/wire/)."""
