"""The forensic toolkit's model: the forensic study (``study``) and its parts (``skull``, ``export``, ``face``,
``objects``), its settings saved in the .blend (``props``). Its operators and panel are in :mod:`operators.ui`
(``forensic_ops``).

Registration is in :mod:`operators` (one list of classes)."""
