"""The running farm: one process serving a cell (the Farm, its listeners, resets, supervision and
event loop, and what `serve` prints: the console and the device table)."""
