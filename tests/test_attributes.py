"""Declared attributes (cip/attribute.py), table-driven over every object a device serves: each
attribute the single services know answers Get_Attribute_Single with its data type's size (and
its encoding decodes back to itself), Set on a gettable attribute without SET access answers 0x0E,
a settable one refuses a value a byte short (0x13) or long (0x15), an attribute with ALL access
only answers 0x14, and Get_Attributes_All is exactly its members' values in id order. Through the
message router, bytes in and bytes out, for a standard adapter (with Parameter objects) and a CIP
Safety target."""

from __future__ import annotations

import pytest

from enip_farm.cip.attribute import GET_ALL, Access, Attribute, CipInstance
from enip_farm.cip.data_types import ELEMENTARY, PADDED_STRING, SHORT_STRING, UINT, UINT_LIST, USINT, Octets
from enip_farm.cip.object import CipClass
from enip_farm.cip.parameter import ParameterObject, ParameterSpec
from enip_farm.config import parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.protocol.cip import ClassCode, MessageRouterReply, Service, decode_reply, encode_request
from enip_farm.protocol.epath import encode_request_path
from enip_farm.protocol.session import MessageContext
from enip_farm.protocol.status import GeneralStatus

T0 = 1_000_000_000
_PARAMETERS = [
    ParameterSpec(1, "speed", 0x0000, 0xC7, 2, 0, 1000, 10),  # settable UINT within 0..1000
    ParameterSpec(2, "gain", 0x0010, 0xCA, 4, default=1.5),  # read-only REAL
    ParameterSpec(3, "odd", 0x0000, 0xC8, 3, default=7, link_path=bytes.fromhex("20042464")),  # a 3-byte UDINT
]


def _device(model: str) -> Device:
    config = parse_config({"devices": [{"name": "d", "address": "127.0.0.1", "model": model}]})
    (profile,) = build_profiles(config, shipped_catalogue())
    device = Device(profile)
    device.router.register(ParameterObject(_PARAMETERS))
    return device


def _ask(device: Device, service: int, class_id: int, instance: int, attribute: int | None = None,
         data: bytes = b"") -> MessageRouterReply:
    request = encode_request(service, encode_request_path(class_id, instance, attribute), data)
    return decode_reply(device.router.handle(request, MessageContext("127.0.0.9", None, (), T0)))


def _cases() -> list[tuple[str, int, int]]:
    cases = []
    for model in ("DSQC1030", "DSQC1042"):
        for class_id, obj in _device(model).router.objects.items():
            for instance_id in (0, *obj.instances):
                cases.append((model, class_id, instance_id))
    return cases


CASES = _cases()


def test_every_object_and_class_code_is_covered() -> None:
    assert {ClassCode(c) for _, c, _ in CASES} == set(ClassCode)  # every class the farm serves, both models
    assert len({(m, c) for m, c, _ in CASES}) == 16  # 7 classes on the adapter (with Parameter), 9 on the safety target


@pytest.mark.parametrize(("model", "class_id", "instance_id"), CASES,
                         ids=[f"{m}-{ClassCode(c).name}-{i}" for m, c, i in CASES])
def test_declared_attributes_answer_as_declared(model: str, class_id: int, instance_id: int) -> None:
    device = _device(model)
    obj: CipClass = device.router.objects[class_id]
    instance = obj.instance(instance_id)
    assert instance is not None
    values = {}
    for attribute in instance.attributes.values():
        get = _ask(device, Service.GET_ATTRIBUTE_SINGLE, class_id, instance_id, attribute.id)
        kind = attribute.type
        if Access.GET not in attribute.access:
            assert attribute.access == Access.ALL
            assert get.general_status == GeneralStatus.ATTRIBUTE_NOT_SUPPORTED
            set_reply = _ask(device, Service.SET_ATTRIBUTE_SINGLE, class_id, instance_id, attribute.id, bytes(6))
            assert set_reply.general_status == GeneralStatus.ATTRIBUTE_NOT_SUPPORTED
            values[attribute.id] = attribute.read()
            continue
        assert get.general_status == GeneralStatus.SUCCESS, attribute
        value = values[attribute.id] = get.data
        if kind.size is not None:
            assert len(value) == kind.size, attribute
        assert kind.size_in(value) == len(value), attribute
        assert kind.encode(kind.decode(value)) == value, attribute
        if Access.SET not in attribute.access:
            refused = _ask(device, Service.SET_ATTRIBUTE_SINGLE, class_id, instance_id, attribute.id, value)
            assert refused.general_status == GeneralStatus.ATTRIBUTE_NOT_SETTABLE, attribute
            continue
        short = _ask(device, Service.SET_ATTRIBUTE_SINGLE, class_id, instance_id, attribute.id, value[:-1])
        long = _ask(device, Service.SET_ATTRIBUTE_SINGLE, class_id, instance_id, attribute.id, value + b"\x00")
        same = _ask(device, Service.SET_ATTRIBUTE_SINGLE, class_id, instance_id, attribute.id, value)
        assert (short.general_status, long.general_status, same.general_status) == (
            GeneralStatus.NOT_ENOUGH_DATA if value else GeneralStatus.SUCCESS,  # an empty value: nothing shorter
            GeneralStatus.TOO_MUCH_DATA, GeneralStatus.SUCCESS), attribute
    all_reply = _ask(device, Service.GET_ATTRIBUTES_ALL, class_id, instance_id)
    members = [a.id for a in instance.attributes.values() if Access.ALL in a.access]
    assert members == sorted(members)
    assert all_reply.general_status == GeneralStatus.SUCCESS
    assert all_reply.data == b"".join(values[i] for i in members)


def test_identity_declares_its_spec_types_and_get_attributes_all_members() -> None:
    identity = _device("DSQC1030").router.objects[ClassCode.IDENTITY].instances[1]
    assert [(a.id, a.type.name, a.access) for a in identity.attributes.values()] == [
        (1, "UINT", GET_ALL), (2, "UINT", GET_ALL), (3, "UINT", GET_ALL),
        (4, "STRUCT of USINT major, USINT minor", GET_ALL), (5, "WORD", GET_ALL), (6, "UDINT", GET_ALL),
        (7, "SHORT_STRING", GET_ALL), (8, "USINT", Access.GET)]
    reply = _ask(_device("DSQC1030"), Service.GET_ATTRIBUTES_ALL, ClassCode.IDENTITY, 1)
    assert len(reply.data) == 2 + 2 + 2 + 2 + 2 + 4 + 1 + reply.data[14]  # attributes 1-7, not 8


def test_tcpip_attribute_7_of_a_device_without_safety_is_six_zero_bytes_in_get_attributes_all_only() -> None:
    device = _device("DSQC1030")
    get = _ask(device, Service.GET_ATTRIBUTE_SINGLE, ClassCode.TCP_IP_INTERFACE, 1, 7)
    assert get.general_status == GeneralStatus.ATTRIBUTE_NOT_SUPPORTED
    listed = _ask(device, Service.GET_ATTRIBUTE_LIST, ClassCode.TCP_IP_INTERFACE, 1, None,
                  UINT_LIST.encode((6, 7)))
    assert listed.general_status == GeneralStatus.ATTRIBUTE_LIST_ERROR
    assert listed.data[-4:] == bytes.fromhex("0700 1400")  # id 7, status 0x14
    everything = _ask(device, Service.GET_ATTRIBUTES_ALL, ClassCode.TCP_IP_INTERFACE, 1).data
    host = PADDED_STRING.size_in(everything[4 * 3 + 6 + 22:])
    assert host is not None
    assert everything[4 * 3 + 6 + 22 + host:][:6] == bytes(6)
    safety = _ask(_device("DSQC1042"), Service.GET_ATTRIBUTE_SINGLE, ClassCode.TCP_IP_INTERFACE, 1, 7)
    assert (safety.general_status, safety.data) == (GeneralStatus.SUCCESS, bytes.fromhex("000000000001"))


def test_parameter_value_takes_its_data_type_and_limits() -> None:
    device = _device("DSQC1030")
    assert _ask(device, Service.GET_ATTRIBUTE_SINGLE, ClassCode.PARAMETER, 1, 1).data == UINT.encode(10)
    too_big = _ask(device, Service.SET_ATTRIBUTE_SINGLE, ClassCode.PARAMETER, 1, 1, UINT.encode(1001))
    assert too_big.general_status == GeneralStatus.INVALID_ATTRIBUTE_VALUE
    assert _ask(device, Service.SET_ATTRIBUTE_SINGLE, ClassCode.PARAMETER, 1, 1, UINT.encode(1000)).general_status == 0
    assert _ask(device, Service.GET_ATTRIBUTE_SINGLE, ClassCode.PARAMETER, 1, 1).data == UINT.encode(1000)
    assert _ask(device, Service.GET_ATTRIBUTE_SINGLE, ClassCode.PARAMETER, 2, 1).data == ELEMENTARY[0xCA].encode(1.5)
    assert _ask(device, Service.GET_ATTRIBUTE_SINGLE, ClassCode.PARAMETER, 3, 1).data == bytes((7, 0, 0))
    assert _ask(device, Service.GET_ATTRIBUTES_ALL, ClassCode.PARAMETER, 3).data == bytes.fromhex(
        "070000" "04" "20042464" "0000" "c8" "03")


def test_a_declaration_says_one_thing_once() -> None:
    with pytest.raises(ValueError, match="attribute 3: settable if and only if it has a setter"):
        Attribute(3, USINT, lambda: 1, access=Access.GET | Access.SET)
    with pytest.raises(ValueError, match="attribute 4: a getter or a constant value, one of them"):
        Attribute(4, USINT, lambda: 1, value=1)
    with pytest.raises(ValueError, match=r"USINT\[6\]: 5 bytes, not 6"):
        Attribute(5, Octets(6), value=bytes(5))
    instance = CipInstance((Attribute(9, SHORT_STRING, value="b"), Attribute(2, USINT, value=1, access=Access.GET)))
    assert list(instance.attributes) == [2, 9]
    assert [a.id for a in instance.all_members] == [9]
    assert instance.get_attributes_all() == b"\x01b"
