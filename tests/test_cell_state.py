"""The controller's state for a person: what blocks a start, the table, the JSON (no RWS here;
the client against the simulated controller: tests/test_cell.py)."""

from __future__ import annotations

import json

from thinkfast.cell.state import (
    KIT_MODULE,
    CellState,
    TaskInfo,
    describe_mode,
    describe_motors,
    format_state,
    start_blockers,
)

ROB1 = TaskInfo("T_ROB1", "normal", "linked", "ready", True, True)
KIT = {"tf_status": "waiting", "tf_start_request": "FALSE", "tf_stop_request": "TRUE"}


def _state(**changes) -> CellState:
    fields = dict(
        url="http://10.0.0.5:80", ctrlstate="motoron", opmode="AUTO", execstate="running",
        cycle="once", speedratio=100.0, tasks=(ROB1,), kit_task="T_ROB1", kit=dict(KIT),
    )  # fmt: skip
    fields.update(changes)
    return CellState(**fields)


def test_a_ready_cell_has_no_blockers():
    assert start_blockers(_state()) == []


def test_every_blocker_is_named_with_its_fix():
    state = _state(opmode="MANR", ctrlstate="guardstop", kit=dict.fromkeys(KIT))
    blockers = start_blockers(state)
    assert len(blockers) == 3
    assert "manual reduced speed (MANR), needs auto" in blockers[0]
    assert "off (guard stop) (guardstop), needs motors on" in blockers[1]
    assert f"load {KIT_MODULE} into T_ROB1" in blockers[2]
    missing = start_blockers(_state(kit_task="T_ROB2"))
    assert missing == ["the controller has no RAPID task T_ROB2"]


def test_modes_and_motor_states_read_as_words_and_unknown_ones_pass_through():
    assert describe_mode("AUTO") == "auto" and describe_mode("XYZ") == "xyz"
    assert describe_motors("emergencystop") == "off (emergency stop)"
    assert describe_motors("weird") == "weird"


def test_the_table_shows_each_task_and_kit_variable():
    text = format_state(_state(kit={**KIT, "tf_stop_request": None, "tf_status": ""}))
    lines = text.splitlines()
    assert lines[0] == "controller   http://10.0.0.5:80"
    assert "motors       on (motoron)" in lines
    assert any(
        line.split() == ["T_ROB1", "normal", "linked", "ready", "on", "true"] for line in lines
    )
    assert '  tf_status         ""' in lines
    assert "  tf_stop_request   (not found)" in lines


def test_json_turns_the_kit_requests_into_booleans():
    out = json.loads(json.dumps(_state().to_json()))
    assert out["kit"] == {
        "task": "T_ROB1", "tf_status": "waiting", "tf_start_request": False,
        "tf_stop_request": True,
    }  # fmt: skip
    assert out["motors_on"] and out["auto"] and out["tasks"][0]["name"] == "T_ROB1"
    assert json.loads(json.dumps(_state(ctrlstate="motoroff").to_json()))["motors_on"] is False


def test_the_kit_module_is_named_for_its_robot_or_generically():
    from thinkfast.cell.state import kit_module

    assert "irb1600" not in KIT_MODULE and "thinkfast-compile kit" in KIT_MODULE
    assert kit_module() == kit_module("") == KIT_MODULE
    here = "ThinkfastEGM.mod from robots/irb2600_12_165/controller/"
    assert kit_module("robots/irb2600_12_165") == kit_module("robots/irb2600_12_165/") == here
    state = _state(kit=dict.fromkeys(KIT), kit_module=kit_module("robots/irb2600_12_165"))
    assert start_blockers(state) == [f"T_ROB1 has no tf_status: load {here} into T_ROB1"]
