"""The simulated camera's GenICam features: one table that places each in the register map and writes
the GenICam XML a client downloads (the names are SFNC's, so any GenICam client finds them).

A feature's register is big-endian, 4 bytes (integers, enumerations, commands) or 8 (IEEE doubles).
Chunk features are read from the frame's chunks, not from registers (docs/camera.md).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from xml.sax.saxutils import escape

from sim.gige import gvcp
from sim.gige.pixels import FORMATS

FEATURES_AT = 0xA000  # device-specific registers start here (below it: the bootstrap registers)
XML_AT = 0x10000  # where the XML file lies in the device's memory
TRUTH_CHUNK_BYTES = 2048  # the simulator's account of a frame: JSON, NUL-padded
CHUNK_IMAGE = 0x1


@dataclass(frozen=True)
class Chunk:
    """One chunk a frame can carry: its SFNC name without "Chunk" (a ChunkSelector entry), its chunk id,
    kind and size in bytes (big-endian, as the registers)."""

    name: str
    chunk_id: int
    kind: str  # "float", "int", "string"
    size: int


CHUNKS: tuple[Chunk, ...] = (
    Chunk("ExposureTime", 0x1001, "float", 8),  # µs
    Chunk("Gain", 0x1002, "float", 8),  # dB
    Chunk("SimulatorTruth", 0x1003, "string", TRUTH_CHUNK_BYTES),
    Chunk("Width", 0x1004, "int", 4),
    Chunk("Height", 0x1005, "int", 4),
    Chunk("Timestamp", 0x1006, "int", 8),  # ns, the frame's GVSP timestamp
)


@dataclass(frozen=True)
class Feature:
    """One feature: its SFNC name, kind, register address and access; what the XML says of it."""

    name: str
    kind: str  # "int", "float", "enum", "command", "string", "bool"
    address: int
    access: str = "RW"  # "RO", "RW", "WO"
    category: str = "DeviceControl"
    minimum: float | None = None
    maximum: float | None = None
    unit: str = ""
    length: int = 4  # string registers: bytes
    entries: dict[str, int] = field(default_factory=dict)
    description: str = ""
    selector: str = ""  # an enumeration selecting which of the feature's registers (4 bytes apart) is meant
    selected: int = 1  # how many registers it has: one per entry of its selector

    @property
    def size(self) -> int:
        return {"float": 8, "string": self.length}.get(self.kind, 4) * self.selected


def _at(i: int) -> int:
    return FEATURES_AT + 8 * i


FEATURES: tuple[Feature, ...] = (
    Feature("DeviceVendorName", "string", gvcp.MANUFACTURER_NAME, "RO", length=32),
    Feature("DeviceModelName", "string", gvcp.MODEL_NAME, "RO", length=32),
    Feature("DeviceVersion", "string", gvcp.DEVICE_VERSION, "RO", length=32),
    Feature("DeviceSerialNumber", "string", gvcp.SERIAL_NUMBER, "RO", length=16),
    Feature("DeviceUserID", "string", gvcp.USER_NAME, "RW", length=16),
    Feature("DeviceFirmwareVersion", "string", 0xA800, "RO", length=32),
    Feature("DeviceTemperature", "float", _at(0), "RO", unit="C", description="The sensor's temperature."),
    Feature("SensorWidth", "int", _at(1), "RO", "ImageFormatControl"),
    Feature("SensorHeight", "int", _at(2), "RO", "ImageFormatControl"),
    Feature("Width", "int", _at(3), "RO", "ImageFormatControl"),
    Feature("Height", "int", _at(4), "RO", "ImageFormatControl"),
    Feature("PixelFormat", "enum", _at(5), "RW", "ImageFormatControl",
            entries={name: f.code for name, f in FORMATS.items()}),
    Feature("TestPattern", "enum", _at(6), "RW", "ImageFormatControl",
            entries={"Off": 0, "GreyDiagonalRamp": 1},
            description="GreyDiagonalRamp: (17 x + 29 y + 997 c) mod 2^bits at column x, row y, channel c."),
    Feature("PayloadSize", "int", _at(7), "RO", "TransportLayerControl"),
    Feature("AcquisitionMode", "enum", _at(8), "RW", "AcquisitionControl",
            entries={"Continuous": 0, "SingleFrame": 1}),
    Feature("AcquisitionStart", "command", _at(9), "WO", "AcquisitionControl"),
    Feature("AcquisitionStop", "command", _at(10), "WO", "AcquisitionControl"),
    Feature("TriggerSelector", "enum", _at(11), "RW", "AcquisitionControl", entries={"FrameStart": 0}),
    Feature("TriggerMode", "enum", _at(12), "RW", "AcquisitionControl", entries={"Off": 0, "On": 1}),
    Feature("TriggerSource", "enum", _at(13), "RW", "AcquisitionControl", entries={"Software": 0}),
    Feature("TriggerSoftware", "command", _at(14), "WO", "AcquisitionControl"),
    Feature("ExposureTime", "float", _at(15), "RW", "AcquisitionControl", 1.0, 3.6e9, "us"),
    Feature("Gain", "float", _at(16), "RW", "AnalogControl", 0.0, 24.0, "dB"),
    Feature("BlackLevel", "float", _at(17), "RW", "AnalogControl", 0.0, 255.0, "DN",
            description="Added to the sensor's own offset, in digital numbers of the sensor's bit depth."),
    Feature("ChunkModeActive", "bool", _at(18), "RW", "ChunkDataControl"),
    Feature("GevHeartbeatTimeout", "int", gvcp.HEARTBEAT_TIMEOUT, "RW", "TransportLayerControl", 500, 600000,
            "ms"),
    Feature("AcquisitionFrameRate", "float", _at(19), "RW", "AcquisitionControl", 0.1, 1000.0, "Hz",
            description="Free-running frames at this rate when AcquisitionFrameRateEnable is set (and the "
                        "exposure allows it); otherwise one frame per exposure."),
    Feature("AcquisitionFrameRateEnable", "bool", _at(20), "RW", "AcquisitionControl"),
    Feature("GevLinkSpeed", "int", _at(21), "RO", "TransportLayerControl", unit="Mbps",
            description="The link's speed: the stream's packets leave no faster than it carries them."),
    Feature("GevSCPD", "int", gvcp.SC_PACKET_DELAY, "RW", "TransportLayerControl", 0, 1_000_000_000,
            description="A delay after each stream packet, in timestamp ticks (ns)."),
    Feature("ChunkSelector", "enum", _at(22), "RW", "ChunkDataControl",
            entries={c.name: i for i, c in enumerate(CHUNKS)}),
    Feature("ChunkEnable", "bool", _at(23), "RW", "ChunkDataControl", selector="ChunkSelector",
            selected=len(CHUNKS), description="Whether the chunk ChunkSelector names is sent (chunk mode)."),
)  # fmt: skip
BY_NAME = {f.name: f for f in FEATURES}
CATEGORIES = ("DeviceControl", "ImageFormatControl", "AcquisitionControl", "AnalogControl", "ChunkDataControl",
              "TransportLayerControl")  # fmt: skip


def _register(
    name: str, kind: str, address: int, access: str, size: int, port: str = "Device", index: str = ""
) -> str:
    """A register node; ``index``: the integer node whose value picks the register, ``size`` bytes apart."""
    tag = {"float": "FloatReg", "string": "StringReg"}.get(kind, "IntReg")
    sign = "<Sign>Unsigned</Sign>" if tag == "IntReg" else ""
    endian = "" if tag == "StringReg" else "<Endianess>BigEndian</Endianess>"
    indexed = f'<pIndex Offset="{size}">{index}</pIndex>' if index else ""
    return (f'<{tag} Name="{name}"><Address>0x{address:x}</Address>{indexed}<Length>{size}</Length>'
            f"<AccessMode>{access}</AccessMode><pPort>{port}</pPort><Cachable>NoCache</Cachable>"
            f"{sign}{endian}</{tag}>")  # fmt: skip


def _node(f: Feature) -> str:
    about = f"<Description>{escape(f.description)}</Description>" if f.description else ""
    reg = f"{f.name}Reg"
    if f.kind == "string":
        return _register(f.name, "string", f.address, f.access, f.length)
    if f.kind == "enum":
        entries = "".join(
            f'<EnumEntry Name="{n}"><Value>{v}</Value></EnumEntry>' for n, v in f.entries.items()
        )
        selects = "".join(f"<pSelected>{s.name}</pSelected>" for s in FEATURES if s.selector == f.name)
        body = f'<Enumeration Name="{f.name}" NameSpace="Standard">{about}{entries}<pValue>{reg}</pValue>'
        body += f"{selects}</Enumeration>"
    elif f.kind == "command":
        body = _command(f.name, reg)
    elif f.kind == "bool":
        body = f'<Boolean Name="{f.name}" NameSpace="Standard"><pValue>{reg}</pValue></Boolean>'
    else:
        tag = "Float" if f.kind == "float" else "Integer"
        # an Integer's bounds are integers (GenApi reads "1e+09" as 1); a Float's, as short as exact
        bounds = "".join(
            f"<{k}>{v if tag == 'Float' else int(v)}</{k}>"
            for k, v in (("Min", f.minimum), ("Max", f.maximum))
            if v is not None
        )
        unit = f"<Unit>{f.unit}</Unit>" if f.unit else ""
        body = (
            f'<{tag} Name="{f.name}" NameSpace="Standard">{about}<pValue>{reg}</pValue>{bounds}{unit}</{tag}>'
        )
    index = f"{f.selector}Reg" if f.selector else ""
    return body + _register(reg, f.kind, f.address, f.access, f.size // f.selected, index=index)


def _chunk(c: Chunk) -> str:
    """A chunk feature (Chunk + its name): read from the frame's chunk of its id (its own port), not
    from a register."""
    name = f"Chunk{c.name}"
    port = f'<Port Name="{name}Port"><ChunkID>{c.chunk_id:x}</ChunkID></Port>'
    if c.kind == "string":
        return _register(name, c.kind, 0, "RO", c.size, f"{name}Port") + port
    tag = "Float" if c.kind == "float" else "Integer"
    feature = f'<{tag} Name="{name}" NameSpace="Standard"><pValue>{name}Reg</pValue></{tag}>'
    return feature + _register(f"{name}Reg", c.kind, 0, "RO", c.size, f"{name}Port") + port


def _command(name: str, register: str) -> str:
    return (f'<Command Name="{name}" NameSpace="Standard"><pValue>{register}</pValue>'
            "<CommandValue>1</CommandValue></Command>")  # fmt: skip


def _masked(name: str, access: str, bits: str, kind: str, extra: str = "") -> str:
    """A stream-channel bootstrap field (SCPS, GigE Vision's bit numbering: 0 is the most significant)."""
    reg = (f'<MaskedIntReg Name="{name}Reg"><Address>0x{gvcp.SC_PACKET_SIZE:x}</Address><Length>4</Length>'
           f"<AccessMode>{access}</AccessMode><pPort>Device</pPort><Cachable>NoCache</Cachable>{bits}"
           f"<Sign>Unsigned</Sign><Endianess>BigEndian</Endianess></MaskedIntReg>")  # fmt: skip
    if kind == "command":
        return _command(name, f"{name}Reg") + reg
    if kind == "bool":
        return f'<Boolean Name="{name}" NameSpace="Standard"><pValue>{name}Reg</pValue></Boolean>' + reg
    return f'<Integer Name="{name}" NameSpace="Standard"><pValue>{name}Reg</pValue>{extra}</Integer>' + reg


def _name(text: str) -> str:
    """``text`` as the schema's names for a model and a vendor must be: [A-Za-z][0-9A-Za-z_]* (a camera's
    XML that breaks it fails GenApi's schema, which Aravis's arv-test and strict GenApi clients check)."""
    name = re.sub(r"[^0-9A-Za-z_]", "_", text)
    return name if name[:1].isalpha() else f"X{name}"


def genicam_xml(model: str, vendor: str, max_packet_bytes: int) -> str:
    """The device's GenICam description (GenApi schema 1.1): categories, features, their registers."""
    in_category = {c: [f.name for f in FEATURES if f.category == c] for c in CATEGORIES}
    in_category["TransportLayerControl"] += [
        "GevSCPSPacketSize",
        "GevSCPSFireTestPacket",
        "GevSCPSDoNotFragment",
    ]
    in_category["ChunkDataControl"] += [f"Chunk{c.name}" for c in CHUNKS]
    categories = "".join(
        f'<Category Name="{c}" NameSpace="Standard">{"".join(f"<pFeature>{n}</pFeature>" for n in names)}</Category>'
        for c, names in in_category.items()
    )  # fmt: skip
    root = "".join(f"<pFeature>{c}</pFeature>" for c in CATEGORIES)
    chunks = "".join(_chunk(c) for c in CHUNKS)
    transport = (
        _masked("GevSCPSPacketSize", "RW", "<LSB>31</LSB><MSB>16</MSB>", "int",
                f"<Min>576</Min><Max>{max_packet_bytes}</Max><Inc>4</Inc>")
        + _masked("GevSCPSFireTestPacket", "RW", "<Bit>0</Bit>", "command")
        + _masked("GevSCPSDoNotFragment", "RW", "<Bit>1</Bit>", "bool")
    )  # fmt: skip
    return (
        '<?xml version="1.0" encoding="utf-8"?>\n'
        f'<RegisterDescription ModelName="{_name(model)}" VendorName="{_name(vendor)}" StandardNameSpace="GEV" '
        'SchemaMajorVersion="1" SchemaMinorVersion="1" SchemaSubMinorVersion="0" MajorVersion="1" MinorVersion="0" '
        'SubMinorVersion="0" ToolTip="hlr-lab simulated camera" ProductGuid="8c2b3a7e-3e0b-4a51-9d67-0a7b6c1d2e01" '
        'VersionGuid="8c2b3a7e-3e0b-4a51-9d67-0a7b6c1d2e02" xmlns="http://www.genicam.org/GenApi/Version_1_1" '
        'xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
        'xsi:schemaLocation="http://www.genicam.org/GenApi/Version_1_1 GenApiSchema_Version_1_1.xsd">\n'
        f'<Category Name="Root" NameSpace="Standard">{root}</Category>\n{categories}\n'
        + "\n".join(_node(f) for f in FEATURES)
        + f"\n{chunks}\n{transport}\n"
        '<Port Name="Device" NameSpace="Standard"/>\n</RegisterDescription>\n'
    )
