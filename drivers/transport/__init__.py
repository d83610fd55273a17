"""What every device driver shares: the byte link (serial, TCP, memory), fake I/O, the reconnect helper and its backoff, the clock and device health."""
