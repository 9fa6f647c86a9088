"""Issue 28, item 1: the cell's topology (enip_farm/topology.py): named groups whose members are
names, patterns, addresses, ranges and subnets, checked like the rest of the configuration, and
`eio import` putting each device in the group of its network."""

from __future__ import annotations

import re

import pytest

from enip_farm.config import ConfigError, parse_config
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.eio.cfg import parse_cfg
from enip_farm.eio.importer import import_eio
from tests.helpers import ROOT

DEVICES = [
    {"name": "rack1-io{n}", "address": "127.0.40.1", "count": 3, "model": "DSQC1030"},
    {"name": "rack2-io{n}", "address": "127.0.40.11", "count": 3, "model": "DSQC1030"},
    {"name": "gripper", "address": "127.0.41.5", "model": "DSQC1030"},
]


def cell(*groups: dict) -> dict:
    return {"devices": DEVICES, "groups": list(groups)}


def test_members_by_name_pattern_address_range_and_subnet() -> None:
    config = parse_config(cell(
        {"name": "rack1", "members": ["rack1-*"]},
        {"name": "switch2", "kind": "switch", "members": ["127.0.40.12-127.0.40.13", "gripper"]},
        {"name": "feed", "kind": "power_feed", "members": ["127.0.40.0/24"]},
        {"name": "ring", "kind": "ring", "members": ["127.0.41.5", "rack2-io1", "rack2-io?"]},
    ))
    topology = config.topology
    assert topology.members("rack1") == ("rack1-io1", "rack1-io2", "rack1-io3")
    assert topology.members("switch2") == ("rack2-io2", "rack2-io3", "gripper")
    assert topology.members("feed") == ("rack1-io1", "rack1-io2", "rack1-io3", "rack2-io1", "rack2-io2", "rack2-io3")
    assert topology.members("ring") == ("rack2-io1", "rack2-io2", "rack2-io3", "gripper")  # configuration order
    assert topology.targets("gripper") == ("gripper",)
    assert topology.targets("rack1") == ("rack1-io1", "rack1-io2", "rack1-io3")
    assert topology.groups_of("gripper") == ("switch2", "ring")
    with pytest.raises(KeyError):
        topology.targets("rack9")
    assert parse_config({"devices": DEVICES}).topology.groups == {}


def test_every_problem_of_the_groups_is_one_line_naming_the_group_and_the_member() -> None:
    with pytest.raises(ConfigError) as caught:
        parse_config(cell(
            {"name": "rack1", "members": ["rack1-*", "rack3-io1", "rack9-*", "127.0.50.1-127.0.50.9"]},
            {"name": "gripper", "members": ["gripper"]},
            {"name": "rack1", "members": ["127.0.40.9-127.0.40.1", "10.0.0.0/8", "10.1.2.3"]},
        ), "cell.yaml")
    assert str(caught.value).splitlines() == [
        "cell.yaml: group 'rack1' (groups[0]), members.1: 'rack3-io1' is not a device of the configuration "
        "(nor a pattern, an address or a range)",
        "cell.yaml: group 'rack1' (groups[0]), members.2: pattern 'rack9-*': no device of the configuration is in it",
        "cell.yaml: group 'rack1' (groups[0]), members.3: address range 127.0.50.1-127.0.50.9: no device of the "
        "configuration is in it",
        "cell.yaml: group 'gripper' (groups[1]), name: 'gripper' is a device's name too: a group needs its own",
        "cell.yaml: group 'rack1' (groups[2]), name: group 'rack1' is defined twice",
        "cell.yaml: group 'rack1' (groups[2]), members.0: address range 127.0.40.9-127.0.40.1: the last address "
        "is below the first",
        "cell.yaml: group 'rack1' (groups[2]), members.1: subnet 10.0.0.0/8: no device of the configuration is in it",
        "cell.yaml: group 'rack1' (groups[2]), members.2: address 10.1.2.3: no device of the configuration is in it",
    ]


@pytest.mark.parametrize(("group", "message"), [
    ({"name": "r", "members": []}, "group 'r' (groups[0]), members: List should have at least 1 item"),
    ({"name": "r", "kind": "cabinet", "members": ["gripper"]}, "group 'r' (groups[0]), kind: Input should be"),
    ({"name": "r s", "members": ["gripper"]}, "group 'r s' (groups[0]), name: String should match pattern"),
    ({"name": "r", "members": ["1.2.3.4.5"]}, "'1.2.3.4.5' is neither a device, a pattern, an address"),
])
def test_a_malformed_group_is_refused_like_any_other_field(group: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(message)):
        parse_config(cell(group))


def test_eio_import_puts_each_device_in_the_group_of_its_network() -> None:
    result = import_eio(parse_cfg((ROOT / "tests" / "data" / "EIO.cfg").read_text(), "EIO.cfg"), shipped_catalogue())
    assert result.document["groups"] == [{"name": "EtherNetIP", "kind": "network",
                                          "members": ["Gripper", "Conveyor", "Vision"]}]
    assert parse_config(result.document).topology.members("EtherNetIP") == ("Gripper", "Conveyor", "Vision")
    assert "groups:\n- name: EtherNetIP\n  kind: network\n  members: [Gripper, Conveyor, Vision]\n" in result.yaml


def test_a_devices_own_network_attribute_names_its_group() -> None:
    text = """EIO:CFG_1.0:6:1::
#
INDUSTRIAL_NETWORK:

      -Name "EtherNetIP1" -Connection "LAN3"

      -Name "EtherNetIP2" -Connection "WAN"
#
ETHERNETIP_DEVICE:

      -Name "a" -Network "EtherNetIP2" -Address "127.0.42.1" -VendorId 75 -ProductCode 1030

      -Name "b" -Address "127.0.42.2" -VendorId 75 -ProductCode 1030

      -Name "c" -Network "Cell net" -Address "127.0.42.3" -VendorId 75 -ProductCode 1030
"""
    result = import_eio(parse_cfg(text, "EIO.cfg"), shipped_catalogue())
    # two EtherNet/IP networks and none named by b: b is in no group
    assert result.document["groups"] == [{"name": "EtherNetIP2", "kind": "network", "members": ["a"]},
                                         {"name": "Cell_net", "kind": "network", "members": ["c"]}]
