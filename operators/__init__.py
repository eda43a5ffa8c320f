"""Everything of PDE Head that touches bpy."""


def register() -> None:
    pass


def unregister() -> None:
    pass
