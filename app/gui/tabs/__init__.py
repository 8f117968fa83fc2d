"""The main window's tabs: each module ``app/gui/tabs/<name>.py`` exposes ``create_tab(lab: LabContext) -> QWidget``.

The main window imports the tabs' modules on a worker thread once it is up (``app/gui/tab_loader.py``) and builds a
tab the first time it is shown; a missing module shows a placeholder. A module may also expose
``create_tab_in_steps(lab) -> (QWidget, Iterator[None])``: the page, and the steps that finish it (each a few tens of
ms), run one per turn of the event loop when the user opens the tab, so the window is never held for the whole page.
"""
