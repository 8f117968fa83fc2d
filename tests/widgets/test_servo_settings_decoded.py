"""The Servo settings page decodes each item as Dynamixel Wizard does (names, named bits, units beside the raw value)
and edits it in either form, refusing what is none of the item's values."""

from __future__ import annotations

import pytest

from app.gui.tabs.hardware import table_rows
from devices import control_table as ct
from widgets.servo_settings_view import ServoSettingsView


@pytest.fixture
def page(qtbot):
    view = ServoSettingsView()
    qtbot.addWidget(view)
    view.set_rows(table_rows())
    view.set_servos([1])
    view.set_enabled(True)
    values = {item.name: item.default for item in ct.XM430_W350_ITEMS}
    values.update({"Baud Rate": 3, "Operating Mode": 3, "Shutdown": 52, "Hardware Error Status": 0b100000})
    view.set_values(1, values)
    return view


def test_enumerations_by_name_bits_by_name_quantities_in_their_units(page):
    assert page.meaning_text("Baud Rate") == "1 Mbps"
    assert page.meaning_text("Operating Mode") == "Position Control"
    assert page.meaning_text("Shutdown") == "Overheating Error, Electrical Shock Error, Overload Error"
    assert page.meaning_text("Hardware Error Status") == "Overload Error"
    assert page.meaning_text("Goal Position") == "180.00 °" and page.value_text("Goal Position") == "2048"
    page.select_item("Shutdown")  # its named bits as check boxes
    assert {page.bit_boxes[b].text().split("  (")[0]: page.bit_boxes[b].isChecked() for b in page.bit_boxes} == {
        "Input Voltage Error": False, "Overheating Error": True, "Motor Encoder Error": False,
        "Electrical Shock Error": True, "Overload Error": True}
    assert "EEPROM" in page.item_title.text()


def test_an_edit_by_name_bits_or_unit_asks_for_the_right_raw_value(page, qtbot):
    with qtbot.waitSignal(page.write_requested) as by_cell:
        page.edit_meaning("Operating Mode", "velocity control")
    assert by_cell.args == [1, "Operating Mode", 1]
    page.select_item("Baud Rate")
    page.choose_name("4 Mbps")
    with qtbot.waitSignal(page.write_requested) as by_list:
        page.item_write.click()
    assert by_list.args == [1, "Baud Rate", 6]
    page.select_item("Shutdown")
    page.bit_boxes[0].setChecked(True)
    with qtbot.waitSignal(page.write_requested) as by_bits:
        page.item_write.click()
    assert by_bits.args == [1, "Shutdown", 53]
    with qtbot.waitSignal(page.write_requested) as by_unit:
        page.edit_meaning("Goal Position", "90 °")
    assert by_unit.args == [1, "Goal Position", 1024]
    # In range, but none of the item's values: refused on the page, the cell shows the servo's value again.
    with qtbot.assertNotEmitted(page.write_requested):
        page.edit("Operating Mode", "2")
        page.edit_meaning("Operating Mode", "Turbo")
        page.edit("Drive Mode", "2")
    assert "sets a bit it does not have" in page.message.text()
    assert page.value_text("Operating Mode") == "3" and page.meaning_text("Operating Mode") == "Position Control"
