"""The forensic study entity's base, and the plain materials of the forensic objects.

:class:`ForensicBase` is what every part of :class:`.study.ForensicStudy` shares (the skull,
:mod:`.skull`; the landmarks, :mod:`.study`; pegs and export, :mod:`.export`;
the face, :mod:`.face`): the study it belongs to (the :class:`operators.study.entity.Study` that holds it as its
``forensic`` component; the study registry is the only one), its collection, settings, forensic
PropertyGroup (:mod:`.props`) and in-memory cache, its sub-collections and the objects the
collection points at.
"""
from __future__ import annotations

import bpy
import numpy as np

from .. import compat
from .props import FORMAT_VERSION, forensic_settings, migrate


class ForensicBase:
    """One study's forensic side, a component of its :class:`operators.study.entity.Study` (``study.forensic``);
    get it with ``ForensicStudy.of(study)``, which also migrates an older file's forensic settings."""

    def __init__(self, study):
        self.study = study

    @staticmethod
    def of(study):
        """The forensic side of ``study`` (a :class:`operators.study.entity.Study`, which holds it as its
        ``forensic`` component), its settings of an older file format migrated first."""
        entity = study.forensic
        if entity.props.format_version < FORMAT_VERSION:
            entity.migrate()
        return entity

    def migrate(self) -> None:
        """The study's forensic state of an older file format into the PropertyGroup (:func:`.props.migrate`;
        not possible while Blender draws: then after the next file load or step)."""
        try:
            migrate(self.collection)
        except AttributeError:     # "Writing to ID classes in this context is not allowed" (a panel's draw)
            pass

    @property
    def collection(self):
        return self.study.collection

    @property
    def name(self) -> str:
        return self.collection.name

    @property
    def settings(self):
        """The study settings (:class:`operators.study.props.PDEHeadStudySettings`)."""
        return self.study.settings

    @property
    def props(self):
        """The forensic settings and state (:class:`.props.PDEHeadForensicSettings`)."""
        return forensic_settings(self.collection)

    @property
    def cache(self) -> dict:
        """The in-memory forensic results: skull segmentation, meshes, depth result, face model."""
        return self.study.cache.forensic

    def sub_collection(self, suffix: str):
        """The study's child collection ``"<study> <suffix>"`` (made when missing)."""
        coll = self.collection
        name = f"{coll.name} {suffix}"
        sub = bpy.data.collections.get(name)
        if sub is None:
            sub = bpy.data.collections.new(name)
        if sub.name not in coll.children:
            coll.children.link(sub)
        return sub

    def linked_object(self, key: str):
        """The object the study collection's custom property ``key`` points at (None when gone)."""
        obj = self.collection.get(key)
        return obj if isinstance(obj, bpy.types.Object) and obj.name in bpy.data.objects else None


def plain_material(name: str, colour):
    mat = bpy.data.materials.get(name)
    if mat is None:
        mat = bpy.data.materials.new(name)
        compat.node_tree(mat)  # nodes on where Blender < 5.0 starts without
        bsdf = mat.node_tree.nodes.get("Principled BSDF")
        bsdf.inputs["Base Color"].default_value = colour
        bsdf.inputs["Roughness"].default_value = 0.6
        mat.diffuse_color = colour
    return mat


def set_material(obj, mat) -> None:
    if obj.data.materials:
        obj.data.materials[0] = mat
    else:
        obj.data.materials.append(mat)


def engine_mesh_of(obj, origin):
    """The mesh of the study object ``obj`` as an engine Mesh in patient mm (its data's coordinates plus the
    study's ``origin``, metres; the object's own transform, e.g. the Frankfurt view, left out), triangulated."""
    from ...pdehead_addon import Mesh
    from ..coords import MM_TO_M

    me = obj.data
    me.calc_loop_triangles()
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    tris = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("vertices", tris)
    vertices = (co.reshape(-1, 3).astype(np.float64) + np.asarray(origin, float)) / MM_TO_M
    return Mesh(vertices, np.zeros((0, 4), np.int64), tris.reshape(-1, 3).astype(np.int64))
