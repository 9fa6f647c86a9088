"""Driving and observing a running farm: signals, device handles, faults, wiring, HTTP API."""
