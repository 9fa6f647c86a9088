"""Captures: reading pcap/pcapng into EtherNet/IP exchanges, golden comparison against a farm,
recording the farm's traffic as pcap, and learning device profiles from captures."""
