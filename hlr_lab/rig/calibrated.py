"""Writing a calibrated rig file: a copy of the operator's file with the estimated fields replaced and a
``[calibration.<procedure>]`` table recording when, from what and how well (comments and layout of the
rest kept: it is the operator's file).

The result is validated as any rig file before it is written, and written atomically; the input file
is never written over unless the caller names it as the output.
"""

from __future__ import annotations

import time
from pathlib import Path

import tomlkit

from hlr_lab import __version__
from hlr_lab.errors import InputError
from hlr_lab.files import atomic_write_text
from hlr_lab.rig.file import Rig, load_rig


def calibrated_rig_text(source_text: str, fields: dict[str, dict], procedure: str, record: dict) -> str:
    """``source_text`` (a rig file) with ``fields`` ({section: {key: value}}) set and the table
    ``[calibration.<procedure>]`` replaced by ``record`` plus the date and hlr-lab's version."""
    doc = tomlkit.parse(source_text)
    for section, values in fields.items():
        table = doc.setdefault(section, tomlkit.table())
        for key, value in values.items():
            table[key] = _plain(value)
    calibration = doc.setdefault("calibration", tomlkit.table(is_super_table=True))
    entry = tomlkit.table()
    entry["date"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    entry["hlr_lab"] = __version__
    for key, value in record.items():
        entry[key] = _plain(value)
    calibration[procedure] = entry
    return tomlkit.dumps(doc)


def write_calibrated_rig(
    source: Path, output: Path, fields: dict[str, dict], procedure: str, record: dict
) -> Rig:
    """Write the calibrated copy of the rig file ``source`` to ``output`` (see the module's docstring);
    returns the rig it describes, read back as any rig file is."""
    text = calibrated_rig_text(source.read_text(encoding="utf-8"), fields, procedure, record)
    scratch = output.with_name(f".{output.name}.check.toml")
    try:
        atomic_write_text(scratch, text)
        load_rig(scratch)  # a calibrated file that hlr-lab could not read is not written
    except InputError as exc:  # named by the file the operator asked for, not the scratch copy
        said = str(exc).removeprefix(f"{scratch}: ").removeprefix(f"{exc.field}: ")
        raise InputError(
            f"the {procedure} calibration's result would be a rig file hlr-lab refuses ({said}); nothing "
            "written: look at the calibration's photographs and summary, then calibrate again",
            path=output,
            field=exc.field,
        ) from None
    finally:
        scratch.unlink(missing_ok=True)
    atomic_write_text(output, text)
    return load_rig(output)


def _plain(value):
    """numpy scalars and arrays as TOML numbers and arrays, rounded to what a rig file needs."""
    if hasattr(value, "tolist"):
        value = value.tolist()
    if isinstance(value, float):
        return round(float(f"{value:.9g}"), 9)  # and no 1e-16 where 0 was meant
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value
