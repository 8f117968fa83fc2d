"""The Servo settings page on the simulated lab shows the servo's items decoded, and an edit by name writes the raw
value the e-manual gives that name."""

from __future__ import annotations

import pytest

from devices.config import SIM_PORT, load_config
from tests.app.windows import open_connected_window


@pytest.fixture
def window(qtbot, sim_lab_fast, tmp_path):
    config = load_config().with_ports(robot=SIM_PORT, board=SIM_PORT, rig=SIM_PORT)
    win = open_connected_window(qtbot, config, tmp_path, 10_000)
    yield win
    win.close()


def test_decoded_items_and_an_edit_by_name(window, qtbot, sim_lab_fast):
    tab = window.show_tab("hardware")
    tab.pages.setCurrentWidget(tab.settings)
    page = tab.settings
    qtbot.waitUntil(lambda: page.values.get("Model Number") == 1020, timeout=10_000)
    chain = sim_lab_fast.chain
    assert page.meaning_text("Model Number") == "XM430-W350"
    assert page.meaning_text("Operating Mode") == "Position Control"
    shutdown = chain.register(1, "Shutdown")
    assert shutdown == 52 and page.meaning_text("Shutdown") == "Overheating Error, Electrical Shock Error, Overload Error"
    assert chain.register(1, "Baud Rate") == 3 and page.meaning_text("Baud Rate") == "1 Mbps"
    # By name, in the panel: Operating Mode → Extended Position Control (raw 4), an EEPROM write, read back.
    page.select_item("Operating Mode")
    page.choose_name("Extended Position Control (Multi-turn)")
    page.item_write.click()
    qtbot.waitUntil(lambda: page.meaning_text("Operating Mode") == "Extended Position Control (Multi-turn)",
                    timeout=10_000)
    assert chain.register(1, "Operating Mode") == 4
    assert "read back" in page.message.text()
