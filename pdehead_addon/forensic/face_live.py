"""The live face: a dragged peg's fast path, and a prepared face model kept in a file.

:class:`.face_from_skull.FaceModel` solves a face through the peg tips; :meth:`~.FaceModel.solve` makes a
whole :class:`~.mesh.Mesh` (topology, UV islands, attributes) every time, which a dragged peg does not
need: the face's topology is fixed by the model's first solve. This module is the Blender-free part of
the live loop:

* :class:`LiveFace` gives the face's vertex positions for new peg tips, the same numbers as
  ``model.solve(tips=...).mesh.vertices`` (checked when it is made: :attr:`LiveFace.exact`), faster:

  - the tissue-depth field's Gaussians over the (row, column) grid are separable on the model's
    cylinder (``exp(-|a - b|^2 / s^2) = exp(-dz^2 / s^2) exp(-chord^2 / s^2)``): two small kernels
    (rows x sites, columns x sites) and one product instead of one kernel of grid x sites;
  - the PDE surface is the model's own (:meth:`FaceModel.surface_head`), evaluated on the mesh's grid by
    gathering each row's four cubic basis weights (not a dense weights x coefficients product) and one
    inverse real FFT; the neck cap's points are the model's own :func:`.surface_mesh.disc_caps`; no
    topology, UVs or attributes are made.

  When the fast path cannot give the same face (a cap that changes its vertex count, a model whose
  field is not the one this module knows), :meth:`LiveFace.positions` returns None and the caller solves
  the whole mesh.
* :func:`model_state` / :func:`model_from_state` keep a prepared :class:`FaceModel` as plain JSON (arrays
  as base64 of their bytes), so a reopened file rebuilds the model in milliseconds instead of preparing
  it again from the skull (seconds: the bone's profile is extracted from the whole skull mesh). No
  pickle: a file's data is never executed.
"""
from __future__ import annotations

import base64
import json
import time
from dataclasses import fields, is_dataclass

import numpy as np

from ..core.provenance import SOFTWARE_VERSION
from ..pde.pde_basis import small_matmul
from ..pde.surface_columns import column_v
from ..pde.surface_mesh import CAP_EDGE, DiscCap, ring_in_plane, star_shaped_ring
from . import face_from_skull as F
from .face_pegs import peg_report

#: Largest difference (mm) between the fast positions and the model's own solve for :attr:`LiveFace.exact`.
EXACT_TOLERANCE_MM = 1e-6
#: What :func:`model_state` does not keep: the sites of the field's grid (made again from the grid), the
#: ears' radial bumps (made again from the landmarks kept, in milliseconds), and what the pegs' report
#: (:mod:`.face_pegs`) caches or reads from the last solve.
_DERIVED = ("_grid_xyz", "_ears", "_front_grid", "_site_disagreement", "_last_limit_shift", "_tip_distance",
            "_smooth_w", "_tip_slack")
#: What :func:`model_state` keeps in single precision: the face's UV layout (texture coordinates need no
#: more; it is half of the text otherwise: 0.56 of 1.14 MB on the phantom), and the bone's raw radius map and its
#: closed hull (what the live face does not read: the raw map is kept for the record, the hull for the
#: constant-depth peer; since the 360-column grid the two maps were 0.6 of 1.5 MB on CThead).
_SINGLE = ("_uv_layout", "hull_profile")
#: What :func:`model_state` keeps in whole hundredths of a mm (uint16): the bone floor, which
#: :meth:`FaceModel.prepare` makes in hundredths itself (so the kept model solves to the bit as the original; in
#: double precision the floor took the phantom's state from 0.72 to 1.2 MB, over its 1 MB budget).
_CENTI_MM = ("bone_floor",)
#: What :func:`model_state` does not keep at all: the bone's raw radius map (nothing reads it after
#: :meth:`FaceModel.prepare`; a rebuilt model has None there). 0.18 MB on CThead's 360-column grid.
_DROPPED = ("raw",)
#: Format of :func:`model_state` (a reader refuses other formats: the caller prepares the model again). 2: the
#: bone floor (on GE a kept model without it would let the bone through the face). 3: the scan's cut plane (a
#: skull without a mandible: the face ends along it). 4: the skin smoothed below the brows (:mod:`.face_skin`): a
#: model kept before would solve to a face other than the one it was saved with. 5: the skin under the chin
#: (:mod:`.face_neck`) and the tips put back as closely as the table's SD allows
#: (:meth:`.face_field.DepthField.tip_slack`). 6: the face made in the head's Frankfurt frame (:mod:`.face_frame`:
#: ``frame_rotation``, ``frame_pivot``; the grid, rule sites and landmarks kept in it) and the nose's lower border
#: (:func:`.face_features.lower_border_within_norms`): a model kept before would solve to another face.
STATE_FORMAT = 6


# ------------------------------------------------------------------------------------------ fast solve
def _gauss(d2: np.ndarray, sigma: float) -> np.ndarray:
    return np.exp(d2 * (-1.0 / (sigma * sigma)))


class LiveFace:
    """The fast path of :meth:`FaceModel.solve` for a dragged peg: vertex positions only.

    Parameters
    ----------
    model : FaceModel
        A prepared model. Its first solve (which fixes the spline's parameter and the neck cap's counts)
        is made here if it was not made yet.
    nu, nv : int, optional
        The mesh's resolution (default: the model's).
    check : bool
        Compare the fast path with the model's own solve now (two solves). False: the caller checks it
        (a model rebuilt from a file, against the face saved with it) and sets :attr:`vertex_count`.

    Attributes
    ----------
    exact : bool
        Whether the fast positions equal the model's own solve (max difference below
        :data:`EXACT_TOLERANCE_MM`) for the table's depths and for one peg moved 3 mm; when False,
        :meth:`positions` always returns None.
    max_difference_mm : float
        The largest difference found in that check.
    vertex_count : int
        The mesh's vertex count (the reference topology; None until known).
    """

    def __init__(self, model, nu: int | None = None, nv: int | None = None, check: bool = True):
        self.model = model
        self.nu = int(nu or model.options["nu"])
        self.nv = int(nv or model.options["nv"])
        nu_ = max(self.nu, 3)
        ref = None
        if check or (nu_, self.nv) not in model.__dict__.get("_cap_refs", {}) or "_pde_fixed" not in model.__dict__:
            ref = model.solve(nu=self.nu, nv=self.nv)                  # fixes _pde_fixed and the cap counts
        self.vertex_count = len(ref.mesh.vertices) if ref is not None else None
        self._u = np.linspace(0.0, 1.0, nu_)[:-1]
        self._cap_ref = model.__dict__.get("_cap_refs", {}).get((nu_, self.nv))
        if not check:             # the caller checks (a model kept in a file: against the saved face)
            self.exact, self.max_difference_mm = True, float("nan")
            return
        self.exact, self.max_difference_mm = False, float("inf")
        try:
            tips0 = model.tips_for(model.default_depths)
            moved = tips0.copy()
            moved[0] = moved[0] + 3.0 * model.peg_normals[0]
            worst = 0.0
            for tips, reference in ((tips0, ref), (moved, model.solve(tips=moved, nu=self.nu, nv=self.nv))):
                fast = self._positions(tips)
                if fast is None or fast.shape != reference.mesh.vertices.shape:
                    worst = float("inf")
                    break
                worst = max(worst, float(np.abs(fast - reference.mesh.vertices).max()))
            self.max_difference_mm = worst
            self.exact = worst <= EXACT_TOLERANCE_MM
        except Exception:                                               # noqa: BLE001 - then the full solve
            self.exact = False

    # -------------------------------------------------------------------- the field
    def offset_field(self, tips: np.ndarray, held=None) -> np.ndarray:
        """The model's tissue-depth offset field (:meth:`FaceModel._offset_field`, the pegs ``held`` never
        damped), with the grid's Gaussians separated into rows x sites and columns x sites."""
        m, g = self.model, self.model.grid
        z, th, r = g.polar(m.field_sites(tips))
        target = r - g.sample(m.profile, z, th)
        xs = m.cylinder_points(z, th)
        sigma = float(m.options["spread_mm"])
        dz2, dc2 = m.site_distances(xs)                                        # (K, n), (M, n)
        Ws = F.peg_kernel(xs, xs, sigma)
        Ez, Et = _gauss(dz2, sigma), _gauss(dc2, sigma)
        EtT = np.ascontiguousarray(Et.T)                      # small_matmul: BLAS threads cost more than these products
        base_g = ((small_matmul(Ez * target, EtT) + F.RULE_WEIGHT * F.RULE_DEPTH_MM)
                  / (small_matmul(Ez, EtT) + F.RULE_WEIGHT))
        base_s = (Ws @ target + F.RULE_WEIGHT * F.RULE_DEPTH_MM) / (Ws.sum(1) + F.RULE_WEIGHT)
        s2 = F.NARROW_FRACTION * sigma
        w = m.correction_weights(xs, target - base_s, m.held_sites(held))
        corr = small_matmul(_gauss(dz2, s2) * w, np.ascontiguousarray(_gauss(dc2, s2).T))
        return m.limited_field(base_g + corr, base_g, xs, target)

    # -------------------------------------------------------------------- the surface on the mesh's grid
    def _grid(self, head) -> np.ndarray:
        """The tube's points on the mesh's grid ((nu - 1, nv, 3)): :meth:`PDEHead.surface_points`, which
        gathers each cubic row's four basis weights instead of a dense rows x (spans x 4) product."""
        density = self.model.__dict__.get("_v_density", [None])[0]
        if density is not None:                                   # columns closer where an outline runs radially
            return head.surface_points(self._u, None, v=column_v(density, self.nv))
        return head.surface_points(self._u, self.nv)

    def _positions(self, tips: np.ndarray, held=None) -> np.ndarray | None:
        m = self.model
        tips = np.asarray(tips, float).reshape(-1, 3)
        radius = m.shaped_radius(self.offset_field(tips, held), tips, held)
        head = m.surface_head(radius, top_z=m.top_z_for(tips))
        if head.vertex is None or self._cap_ref is None:
            return None
        pts = self._grid(head)
        centre = head.spine(np.array([0.0]))[0]
        cap = self._cap_vertices(pts[0], centre)
        if cap is None:                                   # the fan cap of a ring that is not star-shaped
            return None
        out = np.concatenate([pts.reshape(-1, 3), cap, np.asarray(head.vertex, float)[None]])
        self.last_orientation = head.orientation
        return out if self.vertex_count is None or len(out) == self.vertex_count else None

    def _cap_vertices(self, ring: np.ndarray, centre: np.ndarray) -> np.ndarray | None:
        """The neck cap's new points (:class:`.surface_mesh.DiscCap`'s ``vertices`` for the model's cap
        reference), without its triangles: what depends on the counts alone is kept from the first call."""
        if not star_shaped_ring(ring, centre)[0]:
            return None
        fixed = self.__dict__.get("_cap_fixed")
        if fixed is None:                                  # the plan's counts and sample fractions: once
            edge = CAP_EDGE * float(self._cap_ref["edge"])
            probe = DiscCap(ring, centre, edge, self._cap_ref["ends"][0])
            p_ref, r_ref, arc_fraction = self._cap_ref["ends"][0]
            edge = max(float(edge), 1e-9)
            rings = max(1, int(np.ceil(r_ref / edge)))
            f = 1.0 - np.arange(1, rings) / rings
            m = np.maximum(6, np.ceil(f * p_ref / edge).astype(np.int64))
            ring_of = np.repeat(np.arange(len(f)), m)
            first = np.concatenate([[0], np.cumsum(m)[:-1]])
            j = np.arange(m.sum()) - first[ring_of]
            v_frac = np.interp(j / m[ring_of], arc_fraction, np.linspace(0.0, 1.0, len(arc_fraction)))
            idx = v_frac * len(ring)
            lo = np.floor(idx).astype(np.int64)
            fixed = self._cap_fixed = (lo % len(ring), (lo + 1) % len(ring), (idx - lo)[:, None], f[ring_of][:, None],
                                       len(probe.vertices))
        lo, hi, w, fr, count = fixed
        _, e1, e2, p2, _ = ring_in_plane(ring, centre)          # the cap's own frame, as surface_mesh builds it
        q = p2[lo] * (1 - w) + p2[hi] * w
        out = np.concatenate([centre + fr * (q[:, :1] * e1 + q[:, 1:] * e2), np.asarray(centre, float)[None]])
        return out if len(out) == count else None

    def positions(self, tips: np.ndarray, held=None) -> np.ndarray | None:
        """The face's vertex positions (patient mm, (vertex_count, 3)) through the peg ``tips`` ((n, 3),
        patient mm) with the pegs ``held`` (names or a bool array; see :meth:`FaceModel.solve`), in the order of
        the model's mesh; None when only a whole solve gives them (the caller then runs
        :meth:`FaceModel.solve`): the fast path is not :attr:`exact`, or this face's topology differs from the
        reference's."""
        if not self.exact:
            return None
        tips = np.asarray(tips, float).reshape(-1, 3)
        if tips.shape != self.model.peg_bases.shape or not np.all(np.isfinite(tips)):
            return None
        return self._positions(tips, held)

    def report(self, tips: np.ndarray, positions: np.ndarray, held=None):
        """The pegs' report (:func:`.face_pegs.peg_report`) of the face ``positions`` just given by
        :meth:`positions` for these ``tips`` and ``held`` pegs."""
        return peg_report(self.model, tips, positions, held, self.nu, self.nv)

    def provenance(self, tips: np.ndarray, report=None) -> dict:
        """What :meth:`FaceModel.solve` puts in its result's provenance for these tips (and the pegs' ``report``)."""
        m = self.model
        return m.provenance_for(np.einsum("ij,ij->i", np.asarray(tips, float) - m.peg_bases, m.peg_normals), report)


# ------------------------------------------------------------------------------------------ the model kept
def _encode(value):
    if isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        if a.dtype == object:
            raise TypeError("object arrays are not stored")
        return {"__array__": base64.b64encode(a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()).decode(),
                "dtype": a.dtype.newbyteorder("<").str, "shape": list(a.shape)}
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, F.FaceGrid):
        return {"__grid__": {f.name: _encode(getattr(value, f.name)) for f in fields(value)}}
    if isinstance(value, dict):
        if all(isinstance(k, str) for k in value):
            return {"__dict__": {k: _encode(v) for k, v in value.items()}}
        return {"__items__": [[_encode(k), _encode(v)] for k, v in value.items()]}
    if isinstance(value, tuple):
        return {"__tuple__": [_encode(v) for v in value]}
    if isinstance(value, list):
        return [_encode(v) for v in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"{type(value).__name__} is not stored")


def _decode(value):
    if isinstance(value, list):
        return [_decode(v) for v in value]
    if not isinstance(value, dict):
        return value
    if "__array__" in value:
        a = np.frombuffer(base64.b64decode(value["__array__"]), dtype=np.dtype(value["dtype"]))
        return a.reshape(value["shape"]).astype(np.dtype(value["dtype"]).newbyteorder("="))
    if "__grid__" in value:
        return F.FaceGrid(**{k: _decode(v) for k, v in value["__grid__"].items()})
    if "__dict__" in value:
        return {k: _decode(v) for k, v in value["__dict__"].items()}
    if "__items__" in value:
        return {_hashable(_decode(k)): _decode(v) for k, v in value["__items__"]}
    if "__tuple__" in value:
        return tuple(_decode(v) for v in value["__tuple__"])
    raise ValueError(f"unknown stored value {sorted(value)}")


def _cast(value, dtype):
    """``value`` with its floating-point arrays (in dicts, tuples and lists) cast to ``dtype``."""
    if isinstance(value, np.ndarray):
        return value.astype(dtype) if value.dtype.kind == "f" else value
    if isinstance(value, dict):
        return {k: _cast(v, dtype) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return type(value)(_cast(v, dtype) for v in value)
    return value


def _hashable(key):
    return tuple(_hashable(k) for k in key) if isinstance(key, (list, tuple)) else key


def model_state(model) -> str:
    """The prepared ``model`` as one JSON string: its fields and what its first solve fixed (the spline's
    parameter, the neck cap's counts), arrays as base64 of their little-endian bytes. CThead: ~ 0.5 MB."""
    names = {f.name for f in fields(model)} if is_dataclass(model) else set()
    state = {}
    for key, value in model.__dict__.items():
        if key in _DERIVED or key in _DROPPED:
            continue
        try:
            if key in _CENTI_MM and value is not None:
                value = np.round(np.asarray(value) * 100.0).astype(np.uint16)
            state[key] = _encode(_cast(value, np.float32) if key in _SINGLE else value)
        except TypeError:
            if key in names:                       # a field that cannot be kept: the model cannot be rebuilt
                raise
    return json.dumps({"format": STATE_FORMAT, "software": SOFTWARE_VERSION,
                       "fields": sorted(names), "state": state}, separators=(",", ":"))


def model_from_state(text: str):
    """The :class:`FaceModel` kept by :func:`model_state`; ValueError when the text is not one this version
    reads (another format, another software version, a field missing): then prepare the model again."""
    t0 = time.perf_counter()
    try:
        data = json.loads(text)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"the stored face model is not JSON: {exc}") from None
    if data.get("format") != STATE_FORMAT or data.get("software") != SOFTWARE_VERSION:
        raise ValueError(f"the stored face model is format {data.get('format')} of {data.get('software')}, "
                         f"this is format {STATE_FORMAT} of {SOFTWARE_VERSION}")
    names = [f.name for f in fields(F.FaceModel)]
    state = {k: _decode(v) for k, v in data["state"].items()}
    for key in _DROPPED:
        state.setdefault(key, None)
    missing = [n for n in names if n not in state and n != "flags" and n != "prepare_seconds"]
    if missing or sorted(names) != sorted(data.get("fields", [])):
        raise ValueError("the stored face model does not have this version's fields "
                         f"({', '.join(missing) or 'changed'})")
    for key in _SINGLE:
        if key in state:
            state[key] = _cast(state[key], np.float64)
    for key in _CENTI_MM:
        if isinstance(state.get(key), np.ndarray):
            state[key] = state[key].astype(np.float64) / 100.0
    model = F.FaceModel(**{n: state.pop(n) for n in names if n in state})
    model.__dict__.update(state)
    if "_grid_xyz" not in model.__dict__:                 # as prepare makes it (not kept: 3 x the profile's size)
        g = model.grid
        model._grid_xyz = model.cylinder_points(np.repeat(g.z, len(g.theta)), np.tile(g.theta, len(g.z)))
    model.restored_seconds = time.perf_counter() - t0
    return model
