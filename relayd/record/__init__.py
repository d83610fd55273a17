"""Record and replay: every bus event and action of a run in an MCAP file, and the tools
that read it back (docs/RECORDING.md).

- `recorder`: the bus subscriber (event loop side), `writer`: the file thread,
- `codec`: events and actions to JSON and JSON schemas, `foxglove`: Foxglove views,
- `meta`: the file's metadata, `reader`: reading a file with errors that say where,
- `replay`: the recorded inputs through a new brain, compared with the recorded actions.
"""
