"""The files written for an engine that runs a cell beyond one host: Docker Compose, the Swarm
stack, Kubernetes manifests."""
