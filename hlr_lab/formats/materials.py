"""``materials.json`` (docs/formats.md): one Blinn-Phong material per region, with uncertainties.

```json
{"format": "hlr-lab.materials", "version": 1, "model": "blinn-phong",
 "equation": "I = L (rd cos α + rs cos^n β), β between the normal and the half vector",
 "mesh": "bunny8.ply", "sha256": "…",
 "regions": [{"id": 0, "color": [205, 60, 40], "vertices": 4210,
              "rd": [0.62, 0.18, 0.12], "rd_se": […], "rs": [0.2, 0.2, 0.2], "rs_se": […], "n": 80.0, "n_se": 1.2,
              "specular": "measured", "theta_c_deg": 20.0, "pixels": {"diffuse": 36096, "highlight": 4976},
              "residual_rms": 0.004, "estimator": "robust"}]}
```
A region whose highlight could not be measured has ``"specular": "unmeasured"``, a ``reason``, and no
``rs``/``n`` at all: never invented numbers.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, model_validator

from hlr_lab.errors import InputError
from hlr_lab.files import OpenModel, StrictModel, read_format, write_json
from hlr_lab.fitting import EstimatorName, RegionFit
from hlr_lab.formats.regions import Colour8, RegionEntry

MATERIALS_FORMAT = "hlr-lab.materials"
EQUATION = "I = L (rd cos α + rs cos^n β), β between the normal and the half vector"
RGB = Annotated[list[Annotated[float, Field(ge=0)]], Field(min_length=3, max_length=3)]
# a reflectance: above 1 a surface would give more light than it gets; a fit's noise stays well below 1.5
REFLECTANCE = Annotated[list[Annotated[float, Field(ge=0, le=1.5)]], Field(min_length=3, max_length=3)]


class PixelCounts(StrictModel):
    """How many diffuse-only (β > θc) and highlight (β ≤ θc) pixels a region's fit used."""

    diffuse: int = Field(ge=0)
    highlight: int = Field(ge=0)


class MaterialEntry(OpenModel):
    """One region's material: Rd (and, when its highlight was measured, Rs and n), linear RGB, each with
    its standard error; otherwise ``specular = "unmeasured"`` and the ``reason``."""

    id: int = Field(ge=0)
    color: Colour8
    vertices: int = Field(ge=0)
    rd: REFLECTANCE
    rd_se: RGB
    rs: REFLECTANCE | None = None
    rs_se: RGB | None = None
    n: float | None = Field(default=None, gt=0)
    n_se: float | None = Field(default=None, ge=0)
    # systematic: what the rig file's own uncertainty (its calibration records) leaves uncertain; absent
    # where the fit did not propagate it (docs/formats.md)
    rd_sys: RGB | None = None
    rs_sys: RGB | None = None
    n_sys: float | None = Field(default=None, ge=0)
    specular: Literal["measured", "unmeasured"]
    reason: str | None = None
    theta_c_deg: float = Field(gt=0, lt=90)
    pixels: PixelCounts
    residual_rms: float = Field(ge=0)
    estimator: EstimatorName

    @model_validator(mode="after")
    def _specular_consistent(self):
        measured = self.specular == "measured"
        given = [f for f in ("rs", "rs_se", "n", "n_se") if getattr(self, f) is not None]
        if not measured and (self.rs_sys is not None or self.n_sys is not None):
            raise ValueError("an unmeasured specular has no rs_sys or n_sys")
        if measured and len(given) < 4:
            raise ValueError("a measured specular needs rs, rs_se, n and n_se")
        if not measured and (given or not self.reason):
            raise ValueError("an unmeasured specular has a reason and no rs or n")
        return self


class SystematicTerm(OpenModel):
    """One independent one-σ move of the rig the fit believed: what it moves, by how much, and whether
    its σ came from a calibration's covariance, its standard errors, the uncalibrated default, or what the
    radiometric calibration saw of the lamp (a run that did not measure it absolutely)."""

    name: str
    size: str
    source: Literal["covariance", "standard errors", "uncalibrated", "lamp record"]


class Systematic(OpenModel):
    """How ``*_sys`` came about: each term's move of the parameters (first order), added in quadrature."""

    method: Literal["linearised"]
    terms: list[SystematicTerm]
    estimator: EstimatorName
    uncalibrated: str | None = None  # what had no calibration record, and what to do
    placement: str | None = None  # the object's placement assumed, not measured: not in *_sys


class NotMeasured(OpenModel):
    """A planned region without a material: how many usable samples it had and why nothing could be
    told from them (never seen, too few pixels, pixels that do not follow the model)."""

    id: int = Field(ge=0)
    color: Colour8
    vertices: int = Field(ge=0)
    samples: int = Field(ge=0)
    reason: str


class MaterialsFile(OpenModel):
    """``materials.json`` (docs/formats.md): the reflection model, the mesh, one entry per region — a
    material, or in ``not_measured`` why there is none."""

    format: Literal["hlr-lab.materials"]
    version: Literal[1]
    model: Literal["blinn-phong"]
    equation: str = EQUATION
    mesh: str | None = None
    sha256: str | None = None
    # how the entries' *_sys were propagated, and from which terms of the rig's uncertainty
    systematic: Systematic | None = None
    regions: list[MaterialEntry] = Field(min_length=1)
    not_measured: list[NotMeasured] = []


def measured_entry(region: RegionEntry, fit: RegionFit) -> MaterialEntry:
    """The entry of a region whose highlight was measured: Rd, Rs (3,) linear RGB and n, each with its
    standard error, θc and the pixel counts of ``fit``."""
    return MaterialEntry(
        id=region.id,
        color=list(region.color),
        vertices=region.vertices,
        rd=_v(fit.rd),
        rd_se=_v(fit.rd_se),
        rs=_v(fit.rs),
        rs_se=_v(fit.rs_se),
        n=float(fit.n),
        n_se=float(fit.n_se),
        specular="measured",
        theta_c_deg=fit.theta_c_deg,
        pixels=PixelCounts(diffuse=fit.n_diffuse, highlight=fit.n_highlight),
        residual_rms=fit.residual_rms,
        estimator=fit.method,
    )


def unmeasured_entry(
    region: RegionEntry,
    rd,
    rd_se,
    *,
    reason: str,
    theta_c_deg: float,
    pixels: PixelCounts,
    residual_rms: float,
    estimator: EstimatorName,
) -> MaterialEntry:
    """The entry of a region whose highlight could not be measured: its diffuse colour ``rd`` ± ``rd_se``
    ((3,) linear RGB) and the ``reason``, no Rs or n."""
    return MaterialEntry(
        id=region.id,
        color=list(region.color),
        vertices=region.vertices,
        rd=_v(rd),
        rd_se=_v(rd_se),
        specular="unmeasured",
        reason=reason,
        theta_c_deg=theta_c_deg,
        pixels=pixels,
        residual_rms=residual_rms,
        estimator=estimator,
    )


def materials_file(
    entries: list[MaterialEntry],
    *,
    mesh: str | None = None,
    sha256: str | None = None,
    systematic: dict | None = None,
    not_measured: list[NotMeasured] | None = None,
) -> MaterialsFile:
    """``materials.json`` for ``entries`` (ordered by region id), naming the mesh they belong to;
    ``systematic``: how their ``*_sys`` were propagated (:class:`Systematic`'s fields); ``not_measured``:
    the planned regions without an entry, and why."""
    return MaterialsFile(
        format=MATERIALS_FORMAT,
        version=1,
        model="blinn-phong",
        mesh=mesh,
        sha256=sha256,
        systematic=None if systematic is None else Systematic.model_validate(systematic),
        regions=sorted(entries, key=lambda e: e.id),
        not_measured=sorted(not_measured or [], key=lambda e: e.id),
    )


def write_materials(path: str | Path, materials: MaterialsFile) -> None:
    """Write ``materials`` to ``path`` in one piece (a crash leaves the old file or the new one)."""
    write_json(path, materials)


def read_materials(path: str | Path) -> MaterialsFile:
    """Read and validate; an unknown format, version or model, or a malformed field, is one InputError."""
    path = Path(path)
    f = read_format(path, MATERIALS_FORMAT, MaterialsFile)
    ids = [r.id for r in f.regions] + [r.id for r in f.not_measured]
    if len(set(ids)) != len(ids):
        raise InputError("a region id appears twice (in regions or not_measured)", path=path, field="regions")
    return f


def _v(a) -> list[float]:
    return [float(x) for x in a]
