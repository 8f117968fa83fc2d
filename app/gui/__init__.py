"""The Qt face: main window, tabs and the bridges from core/device threads to the GUI thread."""
