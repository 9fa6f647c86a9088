"""Devices built from catalogue profiles (data, not code): identity, assemblies, add-ons."""
