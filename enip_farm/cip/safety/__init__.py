"""CIP Safety (CIP Networks Library Vol. 5) on a farm device: the wire formats (CRCs, safety
network segment, connection parameter CRC, data and time coordination messages), the Safety
Validator state machines of a target (consumer of safe outputs, producer of safe inputs), the
admission of a SafetyOpen and the Safety Supervisor / Safety Validator objects."""
