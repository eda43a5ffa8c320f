"""What a study's step gave, as a value for its caller (an operator, the CLI) to report: the objects it built,
the warnings it added, its seconds and the effective values it chose or measured. The study's steps
(:mod:`operators.study.steps`, :mod:`operators.study.live`) and the forensic steps (:mod:`operators.forensic`)
return these, so they live below both.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class StepOutcome:
    """What a pipeline step gave, for the caller to report: the Blender objects it built or rebuilt, the
    warnings it added to the study (in the engine's words), its seconds (as recorded in the study's timings)
    and the effective values it chose or measured (``values``: e.g. the voxel size of an automatic volume)."""

    step: str
    objects: tuple = ()
    warnings: tuple[str, ...] = ()
    seconds: float = 0.0
    values: dict = field(default_factory=dict)


@dataclass(frozen=True)
class BoundaryOutcome:
    """What :meth:`operators.study.steps.PipelineSteps.boundaries` gave, for the caller to report: the effective
    number of patches t (the study's, reduced to what the scan allows), the curves extracted, the warnings this
    extraction added (in the engine's words) and its seconds."""

    patches: int
    curves: int
    warnings: tuple[str, ...]
    seconds: float
