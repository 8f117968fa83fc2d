"""The Qt-free core: file formats, shapes, teach/play sessions, recording, the live force pipeline and the rig
protocol. Both faces (``app.cli`` and ``app.gui``) call it; an import-linter contract keeps Qt out of it."""
