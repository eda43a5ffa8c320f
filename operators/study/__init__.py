"""The study: one study's entity (``entity``) and its steps (``steps``, ``live``), its state and in-memory cache
(``state``), its settings saved in the .blend (``props``), progress (``progress``), save/reopen
(``persistence``), the cutter's handler (``handlers``) and the one-click run (``pipeline_run``).

Registration is in :mod:`operators` (one list of classes)."""
