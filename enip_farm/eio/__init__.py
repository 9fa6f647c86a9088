"""RobotWare's I/O configuration (EIO.cfg): its file format (`cfg`), a cell configuration made of
a controller's EtherNet/IP devices and signals (`importer`), and the entries a controller needs to
scan the farm's devices (`exporter`)."""
