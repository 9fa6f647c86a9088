"""Sans-IO EtherNet/IP and CIP codec: bytes in, typed messages out, and back. No sockets, no asyncio.

Every wire format of the farm is encoded and decoded here, once; the server, the tests and the tools
share it.
"""
