"""The one place that chooses between the compiled core and the readable numpy reference.

As msgpack-python picks ``_cmsgpack`` or its plain fallback in one place, the agent step picks one of two
namespaces with the same names: :data:`core` (vsfleet._core, what agents run) or :data:`reference` (numpy,
the specification the core is tested against, bit for bit where copies must agree). ``StepConfig.reference``
selects one once (``StepConfig.impl``); the step then calls ``impl.<name>(...)`` with no further choice.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from .advance import advance_structure, advance_structure_reference
from .assembly import assembly_targets, assembly_targets_reference
from .failure import failure_step, failure_step_reference
from .field import build_field, build_field_reference, follow_field, follow_field_reference
from .fit import fit_structure, fit_structure_reference
from .kinematics import integrate_arcs, integrate_arcs_reference
from .safety import safety_filter, safety_filter_reference
from .structure import structure_step_core, structure_step_reference
from .wire import FrameMsg, WireError, decode_frame, decode_frame_core


@dataclass(frozen=True)
class Impl:
    """One implementation of the step's kernels; every field takes the same arguments in both."""

    name: str                     # "core" or "reference"
    structure_step: Callable      # (arrays, metric, pose_world, seen, excluded, judged_apart, elapsed_s, dt_s)
    fit_structure: Callable       # vsfleet.fit
    advance_structure: Callable   # vsfleet.advance
    control: Callable             # (controller, state, ControlInput) -> (state, wheels): vsfleet.control
    safety_filter: Callable       # vsfleet.safety
    failure_step: Callable        # vsfleet.failure
    integrate_arcs: Callable      # vsfleet.kinematics
    build_field: Callable         # vsfleet.field
    follow_field: Callable        # vsfleet.field
    decode_frame: Callable        # (payload, src the key names) -> FrameMsg: vsfleet.wire
    assembly_targets: Callable    # (radii_m, pose_world, seen, points_now, points_next, margin_m, elapsed_s)
                                  # -> (points_now, points_next, detoured): vsfleet.assembly


def _control_core(controller, state, inp):
    """A controller's step in the compiled core (its __call__)."""
    return controller(state, inp)


def _control_reference(controller, state, inp):
    """A controller's step in numpy (its reference method)."""
    return controller.reference(state, inp)


def _decode_frame_reference(payload: bytes, src: str | None = None) -> FrameMsg:
    """wire.decode_frame, with the frame's src checked against the key's (as decode_frame_core checks it)."""
    msg = decode_frame(payload)
    if src is not None and msg.src != src:
        raise WireError(f"src {msg.src!r} is not the key's last chunk")
    return msg


core = Impl("core", structure_step=structure_step_core, fit_structure=fit_structure,
            advance_structure=advance_structure, control=_control_core, safety_filter=safety_filter,
            failure_step=failure_step, integrate_arcs=integrate_arcs, build_field=build_field,
            follow_field=follow_field, decode_frame=decode_frame_core, assembly_targets=assembly_targets)

reference = Impl("reference", structure_step=structure_step_reference, fit_structure=fit_structure_reference,
                 advance_structure=advance_structure_reference, control=_control_reference,
                 safety_filter=safety_filter_reference, failure_step=failure_step_reference,
                 integrate_arcs=integrate_arcs_reference, build_field=build_field_reference,
                 follow_field=follow_field_reference, decode_frame=_decode_frame_reference,
                 assembly_targets=assembly_targets_reference)


def choose(use_reference: bool) -> Impl:
    """The reference namespace when asked for (offline tests of the readable code), else the core's."""
    return reference if use_reference else core
