"""invent-zenoh services: the runtime, the configuration, the CLI and each service."""
