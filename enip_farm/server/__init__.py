"""The only asyncio code that touches sockets. It owns no protocol logic."""
