"""Add-on preferences: where the .vdb volumes of unsaved files go, and defaults."""
from __future__ import annotations

import os
import tempfile

import bpy
from bpy.props import IntProperty, StringProperty

from ..pdehead_addon import defaults as D

# The extension's package (e.g. "bl_ext.user_default.pdehead"; "pdehead_dev" with the dev shim).
ADDON_PACKAGE = __package__.rpartition(".")[0]  # the extension: <package>.operators


def default_vdb_folder() -> str:
    return os.path.join(tempfile.gettempdir(), "pdehead_vdb")


class PDEHeadPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_PACKAGE

    vdb_folder: StringProperty(
        name="Volume Folder (unsaved files)", subtype="DIR_PATH", default="",
        description="Where .vdb volumes are written while the .blend is not saved yet "
                    "(empty: the system temporary folder). Saved files keep them in "
                    "'//pdehead_vdb/' beside the .blend")
    default_patches: IntProperty(name="Default Patches (t)", **D.PATCHES.limits(),
                                 description="Patches of a new study")

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "vdb_folder")
        layout.prop(self, "default_patches")


def preferences(context=None):
    """The add-on preferences, or None when the add-on is not enabled (dev shim, CLI)."""
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_PACKAGE)
    return addon.preferences if addon is not None else None


def vdb_prefs_folder(context=None) -> str:
    prefs = preferences(context)
    folder = prefs.vdb_folder if prefs is not None else ""
    return bpy.path.abspath(folder) if folder else default_vdb_folder()


def default_patches(context=None) -> int:
    prefs = preferences(context)
    return prefs.default_patches if prefs is not None else D.PATCHES.default


CLASSES = (PDEHeadPreferences,)
