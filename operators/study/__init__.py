"""The study: one study's entity (``entity``) and its steps (``steps``, ``live``), its settings saved in the .blend
(``props``), progress (``progress``), save/reopen (``persistence``), the cutter's and the face's handlers
(``handlers``, ``face_handler``), animation (``animation``) and the one-click run (``pipeline_run``). Its state and
in-memory cache: :mod:`operators.state`.

Registration is in :mod:`operators` (one list of classes)."""
