"""Where a drive goes: one output interface, implemented by the MCAP recorder, the Foxglove
WebSocket server and the per-drive files."""
