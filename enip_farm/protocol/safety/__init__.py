"""The CIP Safety protocol (CIP Networks Library Vol. 5), sans-IO: the CRCs, the safety network
segment and its CPCRC, the data and time coordination messages, and the Safety Validator state
machines (consumer and producer) that connections drive with the time passed in. The safety
target's objects and the admission of a SafetyOpen are in cip/safety/."""
