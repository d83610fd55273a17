"""The asyncio runtime around the core: the bus, the device shells, the state and its one writer, health, the supervisor, metrics, logging, sd_notify, virtual time."""
