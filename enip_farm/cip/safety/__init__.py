"""CIP Safety (CIP Networks Library Vol. 5) on a farm device: the admission of a SafetyOpen, the
target's safety state, and the Safety Supervisor / Safety Validator objects. The wire formats and
the Safety Validator state machines are in protocol/safety/. This package builds on cip's generic
modules; they never import it (an import-linter contract): a device wires safety in (device/)."""
