"""The main window's tabs: each module ``app/gui/tabs/<name>.py`` exposes ``create_tab(lab: LabContext) -> QWidget``.

The main window imports a tab's module the first time the tab is shown; a missing module shows a placeholder.
"""
