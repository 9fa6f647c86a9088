"""What a CIP Safety target keeps in its non-volatile memory (CIP Networks Library Vol. 5,
chapter 5, the Safety Supervisor object): its TUNID, a proposed TUNID awaiting Apply_TUNID, its safety
configuration identifier (SCID), the configuration owner (CFUNID), the configuration lock and the
password that Safety_Reset asks for. Sans-IO: the Safety Supervisor object changes it, SafetyOpen
admission reads it.

What each reset keeps (Vol. 5, the Safety_Reset service; Vol. 1, 5-2.4.1 Identity Reset):
- Safety_Reset type 0 and Identity Reset type 0 (power cycle): everything.
- Safety_Reset type 1 (out of box): nothing: the TUNID is unset again (the device waits for one),
  the SCID and CFUNID are cleared, the lock is released, the password goes back to its default.
- Safety_Reset type 2: as type 1, except what the attribute bit map preserves (TUNID, password,
  CFUNID; the OCPUNIDs belong to open connections, which close with any reset).
- Identity Reset type 1 (out-of-box configuration) and type 2 (all but the communication link
  parameters): the safety configuration (SCID, CFUNID, lock) is cleared, the TUNID and password
  are kept, as the safety network number belongs to the device's network identity (farm's reading:
  Vol. 5 leaves the safety configuration's fate on an Identity Reset to the device profile).
"""

from __future__ import annotations

from enip_farm.protocol.safety.segment import Unid

UNID_SIZE = 10
SCID_SIZE = 10
PASSWORD_SIZE = 16
#: A TUNID of all 0xFF bytes: not set (the device waits for one); as a proposal: cancel it.
UNSET_UNID = Unid(b"\xff" * 6, 0xFFFFFFFF)
NO_UNID = Unid(bytes(6), 0)
NO_SCID = bytes(SCID_SIZE)
DEFAULT_PASSWORD = bytes(PASSWORD_SIZE)
#: Safety_Reset type 2's attribute bit map (as Wireshark's CIP Safety dissector names the bits).
PRESERVE_MAC_ID, PRESERVE_BAUD_RATE, PRESERVE_TUNID, PRESERVE_PASSWORD = 0x01, 0x02, 0x04, 0x08
PRESERVE_CFUNID, PRESERVE_OCPUNID, RESERVED_BIT, EXTENDED_MAP = 0x10, 0x20, 0x40, 0x80


class SafetyState:
    """The safety target's settings as they stand, from the farm's configuration at first; a
    type-1 reset returns them to out of box (TUNID unset, no SCID, no owner)."""

    __slots__ = ("tunid", "proposed_tunid", "scid", "cfunid", "locked", "password", "configuration_data")

    def __init__(self, tunid: Unid, scid: bytes) -> None:
        if len(scid) != SCID_SIZE:
            raise ValueError("an SCID has 10 bytes")
        self.tunid = tunid
        self.proposed_tunid: Unid | None = None
        self.scid = scid
        self.cfunid: Unid | None = None
        self.locked = False
        self.password = DEFAULT_PASSWORD
        self.configuration_data = b""  # what the configuration owner's Type 1 SafetyOpen carried

    def configure(self, owner: Unid, scid: bytes, data: bytes) -> None:
        """A Type 1 SafetyOpen was admitted: `owner` owns the configuration `data` signed `scid`."""
        self.cfunid, self.scid, self.configuration_data = owner, scid, data

    @property
    def tunid_set(self) -> bool:
        return self.tunid.snn != UNSET_UNID.snn and self.tunid.node_address != UNSET_UNID.node_address

    def reset(self, kind: int, preserve: int = 0) -> None:
        """Safety_Reset of type `kind` (0, 1 or 2; `preserve`: type 2's attribute bit map)."""
        if kind == 0:
            self.proposed_tunid = None
            return
        keep = preserve if kind == 2 else 0
        self.proposed_tunid = None
        if not keep & PRESERVE_TUNID:
            self.tunid = UNSET_UNID
        if not keep & PRESERVE_PASSWORD:
            self.password = DEFAULT_PASSWORD
        if not keep & PRESERVE_CFUNID:
            self.cfunid = None
        self.scid = NO_SCID
        self.configuration_data = b""
        self.locked = False

    def identity_reset(self, kind: int) -> None:
        """Identity Reset of type `kind`: types 1 and 2 clear the safety configuration."""
        self.proposed_tunid = None
        if kind in (1, 2):
            self.scid = NO_SCID
            self.cfunid = None
            self.configuration_data = b""
            self.locked = False

    def snapshot(self) -> dict[str, str | bool | None]:
        """What a farm restart with state kept restores (hex strings, JSON-friendly)."""
        return {"tunid": self.tunid.encode().hex(), "scid": self.scid.hex(),
                "cfunid": self.cfunid.encode().hex() if self.cfunid else None, "locked": self.locked,
                "password": self.password.hex(), "configuration_data": self.configuration_data.hex()}

    def restore(self, saved: dict) -> None:
        self.tunid = Unid.decode(bytes.fromhex(saved["tunid"]))
        self.scid = bytes.fromhex(saved["scid"])
        self.cfunid = Unid.decode(bytes.fromhex(saved["cfunid"])) if saved.get("cfunid") else None
        self.locked = bool(saved.get("locked", False))
        self.password = bytes.fromhex(saved.get("password", DEFAULT_PASSWORD.hex()))
        self.configuration_data = bytes.fromhex(saved.get("configuration_data", ""))
