"""The forensic toolkit: its operators and panel (``ops``), the forensic study (``study``) and its parts (``skull``,
``export``, ``face``, ``objects``), its settings saved in the .blend (``props``).

Registration is in :mod:`operators` (one list of classes)."""
