"""PDE Head: Blender extension entry point (registers the operators/ package)."""


def register() -> None:
    from . import operators
    operators.register()


def unregister() -> None:
    from . import operators
    operators.unregister()
