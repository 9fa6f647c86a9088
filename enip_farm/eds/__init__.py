"""Electronic Data Sheets (EDS, CIP Networks Library Vol. 1 chapter 7; Vol. 2 for EtherNet/IP): one
written for a catalogue model (`writer.py`), and a catalogue profile read from a vendor's EDS
(`reader.py`)."""
