"""Shared test fixtures.

Qt runs offscreen. Every test must leave no thread running: a test that starts a reader, worker or timer thread
stops it, or this fixture fails it (napari's rule). Hardware tests are skipped unless SENSNAKE_HARDWARE=1.
"""

from __future__ import annotations

import os
import signal
import threading

import pytest

from app.core.lsl_link import LSL_LOOPBACK_CONFIG  # (pylsl itself is imported later, when first used)

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")
# Bus threads at normal priority in tests (and in the processes tests start): run as root, every RobotController
# would get SCHED_FIFO, and a 20x simulated lab's bus thread at real-time priority takes a core from the emulator
# processes and other threads a test waits on. The tests of the real-time path ask for it themselves.
os.environ.setdefault("SENSNAKE_REALTIME", "0")

# The Ctrl-C tests need SIGINT delivered. A shell without job control that starts the run in the background
# (`pytest … &`) leaves SIGINT ignored in it and in every process it starts: put Python's handler back, so the run and
# the CLI processes the tests start (which get the default disposition at exec) take Ctrl-C as a terminal would.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

THREAD_JOIN_GRACE_S = 3.0
MAX_PHYSICS_TEST_SPEED = 4.0  # the physics lab keeps up with this on a loaded 2-core machine (not with 20-50x)
# pytest-qt waits 5 s when a test gives no timeout; on a loaded 2-core machine a Qt timer, a worker thread or the
# window manager can take longer. Those waits get 30 s instead (only a wait that fails takes that long).
QT_DEFAULT_WAIT_MS = 30_000


def pytest_configure(config):
    from pytestqt.qtbot import QtBot

    for name in ("waitUntil", "waitSignal", "waitSignals", "waitExposed", "waitActive", "waitCallback"):
        getattr(QtBot, name).__kwdefaults__["timeout"] = QT_DEFAULT_WAIT_MS


@pytest.fixture(autouse=True, scope="session")
def user_data_folder_of_the_test_run(tmp_path_factory):
    """The per-user data folder (recordings, shapes, calibrations, settings) is a temporary one for the whole run:
    no test reads or writes the real user's folder."""
    previous = os.environ.get("SENSNAKE_DATA_DIR")
    os.environ["SENSNAKE_DATA_DIR"] = str(tmp_path_factory.mktemp("user-data"))
    yield
    if previous is None:
        os.environ.pop("SENSNAKE_DATA_DIR", None)
    else:
        os.environ["SENSNAKE_DATA_DIR"] = previous


@pytest.fixture(autouse=True, scope="session")
def lsl_on_this_machine_only(tmp_path_factory):
    """Lab Streaming Layer traffic of the whole run (and of the processes it starts: the app's simulated lab, the
    real-display probes) stays on this machine: liblsl reads LSLAPICFG once, when first used."""
    config = tmp_path_factory.mktemp("lsl") / "lsl_api.cfg"
    config.write_text(LSL_LOOPBACK_CONFIG, encoding="utf-8")
    previous = os.environ.get("LSLAPICFG")
    os.environ["LSLAPICFG"] = str(config)
    yield
    if previous is None:
        os.environ.pop("LSLAPICFG", None)
    else:
        os.environ["LSLAPICFG"] = previous


@pytest.fixture(autouse=True)
def no_thread_left_running():
    before = set(threading.enumerate())
    yield
    leftover = [t for t in threading.enumerate() if t not in before and t.is_alive()]
    for thread in leftover:
        thread.join(timeout=THREAD_JOIN_GRACE_S)
    still = [t.name for t in leftover if t.is_alive()]
    assert not still, f"test left threads running: {still}"


@pytest.fixture(autouse=True)
def no_qt_timer_left_running(request):
    """Every test that uses Qt stops the QTimers it started (napari's ``dangling_qtimers``): a timer still running
    when the test ends would fire into the next test or into a half-deleted window. Runs after the test's own
    fixtures are torn down (qtbot has closed its widgets by then); timers whose owner Qt has deleted are fine."""
    if "qtbot" not in request.fixturenames:
        yield
        return
    import weakref

    import shiboken6
    from PySide6.QtCore import QTimer

    started: list[weakref.ref] = []
    original_start = QTimer.start

    def start(timer, *args):
        started.append(weakref.ref(timer))
        return original_start(timer, *args)

    QTimer.start = start
    try:
        yield
    finally:
        QTimer.start = original_start
    running = []
    for ref in started:
        timer = ref()
        if timer is not None and shiboken6.isValid(timer) and timer.isActive():
            parent = timer.parent()
            running.append(f"{timer.objectName() or 'QTimer'} (owner {type(parent).__name__ if parent else None}, "
                           f"{timer.interval()} ms)")
    assert not running, f"test left Qt timers running: {sorted(set(running))}"


@pytest.fixture(autouse=True)
def garbage_collected_on_the_gui_thread(request):
    """A Qt test runs as the app does (app/gui/gui_gc.py): no automatic garbage collection, which could free a Qt
    object on a worker thread and deadlock it against the GUI thread (seen: a Calibration-tab test frozen for
    minutes), but a collector on the GUI thread; when the test's widgets are gone, one last collection here."""
    if "qtbot" not in request.fixturenames:
        yield
        return
    from app.gui.gui_gc import GuiThreadCollector

    request.getfixturevalue("qapp")  # the timer needs the application's event loop
    collector = GuiThreadCollector()
    collector.start()
    try:
        yield
    finally:
        collector.stop()
        collector.deleteLater()


def scripted_config(config=None):
    """``config`` (default: the built-in one) with the scripted simulated lab. The app's default is the physics lab
    (MuJoCo), which keeps real time but not 20-50× real time on a loaded machine: tests that run the lab's clock
    fast pin the scripted lab; physics tests pass a config that says ``physics = "mujoco"`` at a modest speed."""
    import dataclasses

    from devices.config import LabConfig

    config = config or LabConfig()
    return dataclasses.replace(config, lab=dataclasses.replace(config.lab, physics="scripted"))


@pytest.fixture(autouse=True, scope="session")
def scripted_process_wide_sim_lab():
    """The process-wide simulated lab (what a ``sim`` port reaches when a test installed none) is the scripted one,
    made up front: the physics lab's stepping thread would outlive the test that first opened a ``sim`` port."""
    from devices import factory
    from devices.sim.lab import SimLab

    previous = factory.install_sim_lab(SimLab(scripted_config()))
    yield
    factory.install_sim_lab(previous)


@pytest.fixture
def install_fast_sim_lab():
    """``install_fast_sim_lab(config=None, seed=1234, speed=20.0)`` builds a seeded simulated lab running ``speed``×
    faster than real time, installs it behind the factory's ``sim`` ports and returns it; removed after the test.
    Without ``config`` it is the scripted lab (:func:`scripted_config`); a physics test passes its own config."""
    from devices import factory
    from devices.sim.lab import SimLab

    previous: list[object] = []

    def install(config=None, *, seed: int = 1234, speed: float = 20.0):
        config = config or scripted_config()
        if config.lab.physics != "scripted" and speed > MAX_PHYSICS_TEST_SPEED:
            raise ValueError(f"a physics lab at {speed}x real time lags on a loaded machine: run it at <= "
                             f"{MAX_PHYSICS_TEST_SPEED}x, or pin the scripted lab (scripted_config(config))")
        lab = SimLab(config, seed=seed, speed=speed)
        replaced = factory.install_sim_lab(lab)
        if not previous:
            previous.append(replaced)
        return lab

    yield install
    if previous:
        factory.install_sim_lab(previous[0])


@pytest.fixture
def sim_lab_fast(install_fast_sim_lab):
    """A seeded simulated lab running 20× faster than real time, installed for the test and removed after."""
    return install_fast_sim_lab()


class OneDeviceLab:
    """Stands in for the simulated lab with one device endpoint (``"board"``, ``"rig"``, …): tests of one driver do
    not need the other simulators running."""

    def __init__(self, device: str, endpoint: object) -> None:
        self.device, self._endpoint = device, endpoint

    def endpoint(self, device: str) -> object:
        assert device == self.device, f"this test installed only the {self.device!r} simulator, not {device!r}"
        return self._endpoint


@pytest.fixture
def install_sim_device():
    """``install_sim_device(device, endpoint)`` routes the factory's ``sim`` port of that device kind to
    ``endpoint`` and returns it; the previous lab is back when the test ends."""
    from devices import factory

    previous: list[object] = []

    def install(device: str, endpoint: object) -> object:
        lab = factory.install_sim_lab(OneDeviceLab(device, endpoint))
        if not previous:
            previous.append(lab)
        return endpoint

    yield install
    if previous:
        factory.install_sim_lab(previous[0])


# Modules whose tests measure wall-clock behaviour (paint rates on a real display, loop periods, a rig or a board
# paced in real time), or share something machine-wide (LSL discovery on the loopback, a Dask scheduler): they run
# after the rest has run on several workers (scripts/test.sh), on one worker per core — these mostly wait, together
# they keep about half a core busy — each module whole on one worker, and the modules that share a machine-wide
# resource (SHARED_RESOURCE) on one worker together. A single test elsewhere can ask for the same with
# ``@pytest.mark.serial``.
SERIAL_MODULES = (
    "tests/realdisplay/",
    "tests/app/test_mocap_gui.py",
    "tests/app/test_mocap_lsl.py",
    "tests/devices/test_sim_mocap_stream.py",
    "tests/app/test_controller_science.py",
    "tests/app/test_dask_worker_kill.py",
    "tests/devices/test_controller_timing.py",
    "tests/devices/test_loop_process.py",
    "tests/devices/test_servo_chain.py",
    "tests/devices/test_dxl_pty.py",
    "tests/app/test_play_pty.py",
    "tests/app/test_force_page.py",
    "tests/app/test_main_window_lab_process.py",
    "tests/app/test_hardware_settings.py",
    "tests/app/test_record_emulated.py",
    "tests/devices/test_servo_chain_emulator.py",
    "tests/devices/test_rig_emulated.py",
)


# What only one test at a time may use, and the modules using it: LSL discovery (a test resolving a MoCap stream by
# type would find another's) and Dask schedulers.
SHARED_RESOURCE = {
    "lsl": ("tests/app/test_mocap_gui.py", "tests/app/test_mocap_lsl.py", "tests/devices/test_sim_mocap_stream.py",
            "tests/realdisplay/test_mocap_view.py"),
    "dask": ("tests/app/test_controller_science.py", "tests/app/test_dask_worker_kill.py"),
}


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist's own hook reads the xdist_group marks (--dist loadgroup)
def pytest_collection_modifyitems(config, items):
    serial = pytest.mark.serial
    for item in items:
        path = item.nodeid.split("::", 1)[0]
        if path.startswith(SERIAL_MODULES):
            item.add_marker(serial)
        if item.get_closest_marker("serial") is not None:
            group = next((name for name, modules in SHARED_RESOURCE.items() if path in modules), path)
            item.add_marker(pytest.mark.xdist_group(group))
    if os.environ.get("SENSNAKE_HARDWARE") == "1":
        return
    skip = pytest.mark.skip(reason="needs real hardware (set SENSNAKE_HARDWARE=1)")
    for item in items:
        if "hardware" in item.keywords:
            item.add_marker(skip)


@pytest.fixture
def emulator():
    """The independent XM430 chain (tests/emulators/xm430_emulator.py) in its own process on a pty; it must end
    cleanly when the test is done."""
    from tests.emulators.xm430_emulator import EmulatorProcess

    process = EmulatorProcess()
    try:
        yield process
    finally:
        assert process.close() == 0
