"""A cell across processes and hosts: its slices, `serve --workers N`, the fleet's and the shards'
one HTTP API."""
