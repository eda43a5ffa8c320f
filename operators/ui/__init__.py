"""The user interface: the pipeline's operators (``ops``), the forensic toolkit's operators and panel
(``forensic_ops``), their one ``execute`` (``base``), the sidebar panels (``panel``) and the import dialog's loader
options (``import_options``). The preferences: :mod:`operators.prefs`.

Registration is in :mod:`operators` (one list of classes)."""
