"""The CIP object model: one module per object class, dispatched by the message router."""
