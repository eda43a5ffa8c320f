"""The user interface: the pipeline's operators (``ops``), their one ``execute`` (``base``), the sidebar panels
(``panel``), the import dialog's loader options (``import_options``) and the preferences (``prefs``).

Registration is in :mod:`operators` (one list of classes)."""
