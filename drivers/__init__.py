"""Device drivers for relayd: one package per device protocol, no convoy logic.

Each package separates a pure codec (bytes in, typed frames out, no asyncio), an
asyncio driver that owns the transport and its reconnects, and a protocol-true fake
that plays the device's side for tests and the simulator.
"""
