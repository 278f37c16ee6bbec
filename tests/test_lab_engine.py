"""The lab's engine thread without a browser: commands, series for many readers, files, errors."""

import json
import math
import os
import re
import time
from pathlib import Path

import numpy as np
import pytest

from granlab.app.lab.buffers import Cursor, SeriesBuffer
from granlab.app.lab.engine_thread import LabEngine, safe_path
from granlab.engine import ParameterError
from granlab.engine.params import Load
from granlab.engine.io import h5md


def wait(predicate, timeout=60.0):
    deadline = time.time() + timeout
    while time.time() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError("condition not met in time")


def last_message(engine, seq=0):
    """(level, text) of the messages after sequence number ``seq``."""
    return [(m.level, m.text) for m in engine.messages.since(seq)]


@pytest.fixture
def engine(tmp_path):
    lab = LabEngine(tmp_path, preset="ratchet16", speed=math.inf)
    lab.start()
    wait(lambda: lab.status()["step"] > 0)
    yield lab
    lab.stop()
    assert not lab.alive


@pytest.mark.parametrize("name", ["../escape.h5", "/tmp/abs.h5", "sub/run.h5", "..", ".hidden", "a" * 101, "",
                                  "bad name.h5"])
def test_safe_path_refuses_anything_but_a_plain_name(tmp_path, name):
    with pytest.raises(ParameterError, match="plain name"):
        safe_path(tmp_path, name)


def test_safe_path_adds_h5_inside_the_data_folder(tmp_path):
    assert safe_path(tmp_path, "run1") == tmp_path / "run1.h5"
    assert safe_path(tmp_path, "run-2.h5") == tmp_path / "run-2.h5"


def lists(columns: dict) -> dict:
    return {name: values.tolist() for name, values in columns.items()}


def test_series_buffer_serves_each_reader_what_it_has_not_seen():
    buffer = SeriesBuffer(("t", "x"), capacity=5)
    first, second = Cursor(), Cursor()
    buffer.extend([(0.0, 1.0), (1.0, 2.0)])
    first, reset, columns = buffer.since(first)
    assert all(values.dtype == np.float64 for values in columns.values())  # no Python float per value
    assert reset and lists(columns) == {"t": [0.0, 1.0], "x": [1.0, 2.0]}
    buffer.extend([(2.0, 3.0)])
    first, reset, columns = buffer.since(first)
    assert not reset and columns["t"].tolist() == [2.0]
    second, reset, columns = buffer.since(second)
    assert reset and columns["t"].tolist() == [0.0, 1.0, 2.0]
    buffer.extend([(float(k), 0.0) for k in range(3, 10)])  # beyond the capacity: the oldest go
    first, reset, columns = buffer.since(first)
    assert not reset and columns["t"].tolist() == [5.0, 6.0, 7.0, 8.0, 9.0]
    assert buffer.array()[:, 0].tolist() == [5.0, 6.0, 7.0, 8.0, 9.0] and len(buffer) == 5
    buffer.extend(np.array([[10.0, 0.0], [11.0, 0.0]]))  # wraps around the end of the ring
    first, reset, columns = buffer.since(first)
    assert not reset and columns["t"].tolist() == [10.0, 11.0]
    buffer.extend([(float(k), 0.0) for k in range(12, 30)])  # more than the capacity at once
    first, reset, columns = buffer.since(first)
    assert columns["t"].tolist() == [25.0, 26.0, 27.0, 28.0, 29.0]
    buffer.reset(("t", "y"))
    first, reset, columns = buffer.since(first)
    assert reset and lists(columns) == {"t": [], "y": []}


def resident_bytes() -> int:
    return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def test_a_buffer_takes_its_memory_when_it_is_made_not_as_rows_come():
    """A lab's resident memory grew for half an hour as its buffers filled (np.zeros leaves pages untouched)."""
    before = resident_bytes()
    buffer = SeriesBuffer(tuple("abcdefghi"), 400_000)
    assert resident_bytes() - before >= 0.9 * buffer.nbytes == 0.9 * 400_000 * 9 * 8


def test_a_preset_switch_drops_the_buffers_the_new_preset_does_not_fill(engine):
    wait(lambda: set(engine.status()["memory"]["series_mib"]) == {"time", "cycles", "contacts"})
    engine.submit("preset", name="block")
    wait(lambda: engine.status()["preset"] == "block")
    memory = wait(lambda: engine.status()["memory"])
    assert set(memory["series_mib"]) == {"block"} and set(engine.buffers) == {"block"}
    assert memory["history_limit_mib"] == 64.0 and 0.0 <= memory["series_filled"]["block"] <= 1.0
    _, reset, columns = engine.series("contacts", Cursor())
    assert reset and columns == {}


def test_rows_and_status_name_the_run_they_belong_to(engine):
    """A page draws rows only with a status of the same run: a switch's rows never meet the last
    preset's labels (the switch resets the buffers before the status says the new preset)."""
    run = engine.status()["run"]
    cursor, _, _ = engine.series("contacts", Cursor())
    assert cursor.run == run
    engine.submit("preset", name="block")
    wait(lambda: engine.status()["preset"] == "block")
    assert engine.status()["run"] == run + 1
    assert engine.series("contacts", cursor)[0].run == engine.series("block", Cursor())[0].run == run + 1
    engine.submit("reset")
    wait(lambda: engine.status()["run"] == run + 2)


def test_a_control_reaches_the_engine_between_steps(engine):
    engine.submit("apply", changes={"damping_ratio": 0.45})
    wait(lambda: engine.status()["settings"]["damping_ratio"] == 0.45, timeout=5.0)
    assert engine.source.sim.law.damping_ratio == 0.45
    assert engine.status()["command_ms"] > 0.0  # how long the control waited in the queue
    # friction waits for the end of the frictionless compression, the status shows it at once
    engine.submit("apply", changes={"friction": 0.45})
    wait(lambda: engine.status()["settings"]["friction"] == 0.45, timeout=5.0)
    engine.submit("apply", changes={"friction": math.inf})
    wait(lambda: engine.status()["settings"]["friction"] == "inf", timeout=5.0)


def test_an_invalid_control_is_refused_and_the_run_goes_on(engine):
    seq = engine.messages.latest_seq
    engine.submit("apply", changes={"damping_ratio": 1.5})
    wait(lambda: last_message(engine, seq))
    message = engine.messages.since(seq)[-1]
    assert message.level == "error" and message.control == "damping_ratio"
    assert message.text.startswith("Damping ζ = 1.5 is not allowed: a fraction of critical damping in [0, 1)")
    status = engine.status()
    assert status["settings"]["damping_ratio"] == 0.3 and status["state"] == "running"
    step = status["step"]
    wait(lambda: engine.status()["step"] > step)


def test_the_engine_copies_a_frame_only_once_the_last_was_taken(engine):
    seq, frame = engine.frame(timeout=1.0)
    assert frame is not None and frame.positions.shape == (16, 2)
    time.sleep(0.5)  # 15 publishing ticks at 30 frames/s, and no frame taken
    newer, frame = engine.frame(seen=seq)
    assert newer == seq + 1 and frame is not None  # one copy, made once the first was taken
    step = engine.status()["step"]
    later, frame = engine.frame(seen=newer, timeout=2.0)
    assert later == newer + 1 and frame is not None
    wait(lambda: engine.status()["step"] > step)


def test_pause_step_and_play(engine):
    engine.submit("pause")
    wait(lambda: engine.status()["state"] == "paused")
    step, t = engine.status()["step"], engine.status()["time"]
    time.sleep(0.3)
    assert engine.status()["step"] == step
    rows = len(engine.buffers["time"])
    engine.submit("step")  # to the next sample time: one more row of a series
    wait(lambda: engine.status()["step"] > step)
    status = engine.status()
    interval = engine.source.cycle_time() / engine.source.samples_per_cycle
    assert 0 < status["time"] - t <= interval + status["dt"] and status["state"] == "paused"
    engine.submit("play")
    wait(lambda: engine.status()["time"] > status["time"] + interval)
    assert len(engine.buffers["time"]) > rows


def test_a_long_step_runs_in_chunks_and_pause_ends_it_at_once(engine):
    """A step to the next sample time may be millions of steps (a preset sampled once per 100
    load cycles here): it runs in chunks between which commands are answered."""
    engine.submit("pause")
    wait(lambda: engine.status()["state"] == "paused")
    preset = engine.source  # sampled once per 100 load cycles: a step of 1.3 million steps
    preset.samples_per_cycle = preset.path_samples_per_cycle = 0.01
    preset.settings = preset.settings.replace(frames_per_cycle=0.01)
    preset._restart_clock()
    step = engine.status()["step"]
    engine.submit("step")
    wait(lambda: engine.status()["state"] == "stepping" and engine.status()["step"] > step)
    assert 0.0 < engine.status()["step_progress"] < 1.0
    submitted = time.perf_counter()
    engine.submit("pause")
    wait(lambda: engine.status()["state"] == "paused", timeout=5.0)
    assert time.perf_counter() - submitted < 0.5 and engine.status()["command_ms"] < 200.0
    step = engine.status()["step"]
    time.sleep(0.3)
    assert engine.status()["step"] == step


def test_a_file_that_would_hold_its_reader_is_refused_while_the_run_goes_on(engine, tmp_path):
    """An extended XYZ file whose last count line says 10^12 atoms: the reading, in a process of
    its own, names the frame and the count; the simulation never stops."""
    packing = (Path(__file__).parent / "data" / "lammps" / "packing.xyz").read_text()
    (tmp_path / "bad.xyz").write_text(packing + "1000000000000\ncomment\n1 2 3\n")
    step = engine.status()["step"]
    seq = engine.messages.latest_seq
    engine.submit("load", name="bad.xyz")
    wait(lambda: engine.status()["jobs"])
    wait(lambda: any(m.level == "error" for m in engine.messages.since(seq)))
    error = [m for m in engine.messages.since(seq) if m.level == "error"][-1]
    assert error.control == "load"
    assert "bad.xyz, frame 1: the count line says 1000000000000 particles, but only 14 bytes follow it" in error.text
    status = engine.status()
    assert status["preset"] == "ratchet16" and status["state"] == "running" and status["step"] > step
    assert not status["jobs"]


def test_the_simulation_keeps_stepping_while_a_save_is_written(engine, tmp_path):
    wait(lambda: engine.status()["time"] > 5.0)
    engine.submit("save", name="during")
    job = wait(lambda: engine.status()["jobs"])[0]
    assert job["kind"] == "save" and job["label"] == "saving during.h5"
    step = engine.status()["step"]
    wait(lambda: engine.status()["step"] > step + 1000 and engine.status()["jobs"])  # stepping, still saving
    (tmp_path / ".other.x1y2.part.h5").write_bytes(b"")  # a save's file before it is complete
    assert ".other.x1y2.part.h5" not in engine.saved_files()  # is not offered for replay
    wait(lambda: (tmp_path / "during.h5").exists(), timeout=60.0)
    with h5md.open_run(tmp_path / "during.h5") as f:
        assert h5md.frame_count(f) >= 2
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == [".other.x1y2.part.h5"]  # none left


def test_a_diverging_run_pauses_with_an_error_and_keeps_its_last_good_state(engine):
    wait(lambda: engine.status().get("cycle", 0) >= 1)
    seq = engine.messages.latest_seq
    engine.submit("apply", changes={"pressure": 1e5})  # the lab's bounds refuse what would crush the disks
    wait(lambda: last_message(engine, seq))
    assert "a pressure from 0.01 to 5 (K_N / P0 from 10⁴ to 20" in last_message(engine, seq)[-1][1]
    engine.submit("pause")
    wait(lambda: engine.status()["state"] == "paused")
    # a wall load 10^5 times the stiffness scale (as a notebook may set) crushes the disks into each other
    engine.source.sim.set_wall_load("top", Load(base=1e5))
    engine.submit("play")
    wait(lambda: engine.status()["state"] == "error")
    status = engine.status()
    assert "overlap" in status["error"] and "Paused" in status["error"] and not engine.running
    sim = engine.source.sim
    position, step = sim.particles.position.copy(), sim.step
    assert np.all(np.isfinite(position))
    overlap = sim.contact_snapshot().surface_gap
    assert -overlap.min() < sim.integration.max_overlap * sim.particles.radius.min()
    time.sleep(0.3)
    assert sim.step == step and np.array_equal(sim.particles.position, position)


def test_save_then_replay_then_back_to_a_preset(engine, tmp_path):
    """A lab run file holds the frames kept by simulated time with the settings of each, the lab's
    series and the cycle records; its replay shows a frame and the series up to its time."""
    wait(lambda: engine.status().get("cycle", 0) >= 1)
    engine.submit("apply", changes={"amplitude": 0.25})  # from the next cycle on
    wait(lambda: engine.status().get("cycle", 0) >= 3)
    engine.submit("save", name="lab-run")
    wait(lambda: "lab-run.h5" in engine.saved_files())
    with h5md.open_run(tmp_path / "lab-run.h5") as f:
        frames = h5md.frame_count(f)
        first, last = h5md.read_frame(f, 0), h5md.read_frame(f, frames - 1)
        series = h5md.lab_series(f)
    assert last["position"].shape == (16, 2)
    assert frames >= 10 * 3  # ten frames a cycle, compression included
    assert json.loads(first["lab_settings_json"])["amplitude"] == 0.2
    assert json.loads(last["lab_settings_json"])["amplitude"] == 0.25
    assert first["lab_phase"] == "compressing to P0 = 1"  # what a movie's caption says of each frame
    assert re.fullmatch(r"cycle [3-9] · q = 0\.\d{3}, (rising|falling)", last["lab_phase"])
    assert set(series) == {"time", "cycles", "contacts"} and series["time"][0] == engine.source.series["time"]
    info = h5md.summary(tmp_path / "lab-run.h5")
    assert info["cycles"] == len(series["cycles"][1]) >= 4 and info["protocol"]["lab_preset"] == "ratchet16"

    engine.submit("load", name="lab-run.h5")
    wait(lambda: engine.status()["preset"] == "replay:lab-run.h5")
    engine.submit("pause")
    engine.submit("seek", index=frames - 1)
    status = wait(lambda: engine.status() if engine.status()["replay"]["frame"] == frames - 1 else None)
    assert status["replay"] == {"of": "ratchet16", "frame": frames - 1, "frames": frames, "plot": "replay-energy",
                                "start": first["time"], "end": last["time"]}
    assert status["settings"]["amplitude"] == 0.25 and status["time"] == last["time"]
    _, reset, columns = engine.series("time", Cursor())
    assert columns["t"][-1] <= last["time"] and len(columns["t"]) == np.sum(series["time"][1][:, 0] <= last["time"])
    engine.submit("seek", index=0)
    wait(lambda: engine.status()["replay"]["frame"] == 0)
    _, reset, columns = engine.series("time", Cursor())
    assert max(columns["t"]) <= first["time"]
    seq = engine.messages.latest_seq
    engine.submit("save", name="again")
    wait(lambda: last_message(engine, seq))
    assert "a running preset" in last_message(engine, seq)[-1][1]
    engine.submit("preset", name="block")
    wait(lambda: engine.status()["preset"] == "block")


def test_the_closed_path_saves_and_replays_every_pair_named_by_its_spring(tmp_path):
    lab = LabEngine(tmp_path, preset="closed-path", speed=math.inf)
    lab.start()
    try:
        wait(lambda: lab.status()["time"] > 1.0)
        lab.submit("save", name="loops")
        wait(lambda: "loops.h5" in lab.saved_files(), timeout=60.0)
        with h5md.open_run(tmp_path / "loops.h5") as f:
            last = h5md.read_frame(f, -1)
            assert h5md.read_checkpoint(f) is None  # four laws in one file: nothing to resume
        assert last["position"].shape == (8, 2) and last["contacts"]["pair"].tolist() == [[0, 1], [2, 3], [4, 5], [6, 7]]
        assert re.fullmatch(r"loop \d+ · [ABCD] → [ABCD]", last["lab_phase"])
        lab.submit("load", name="loops.h5")
        wait(lambda: lab.status()["preset"] == "replay:loops.h5")
        frame = wait(lambda: lab.frame(timeout=1.0)[1])
        assert len(frame.radii) == 8
        assert [text for text, _, _ in frame.labels] == ["Cundall–Strack", "α-corrected", "angle-based",
                                                          "LAMMPS hooke/history"]
    finally:
        lab.stop()


def test_a_save_never_writes_over_a_file_nor_follows_a_link_planted_in_the_data_folder(engine, tmp_path):
    outside = tmp_path.parent / f"{tmp_path.name}-outside.h5"
    outside.write_bytes(b"precious")
    for planted in ("victim.h5.part", ".victim.h5.part", "victim.part.h5", "taken.h5"):
        (tmp_path / planted).symlink_to(outside)
    wait(lambda: engine.status()["time"] > 0.0)
    seq = engine.messages.latest_seq
    engine.submit("save", name="victim")
    # the save's own message, which comes after its file: a refusal asked for later is then the latest message
    wait(lambda: any(text.startswith("saved") for _, text in last_message(engine, seq)))
    assert outside.read_bytes() == b"precious" and not (tmp_path / "victim.h5").is_symlink()
    assert h5md.summary(tmp_path / "victim.h5")["protocol"]["lab_preset"] == "ratchet16"
    for name, allowed in (("taken", "a file inside the lab's data folder"),
                          ("victim", "a name not yet in the data folder (victim-2.h5 is free)")):
        seq = engine.messages.latest_seq
        engine.submit("save", name=name)
        wait(lambda: last_message(engine, seq))
        assert last_message(engine, seq)[-1][1] == f"file name = {name} is not allowed: {allowed}"
    assert outside.read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir() if not p.is_symlink()) == ["victim.h5"]


def test_refused_file_names_leave_the_data_folder_untouched(engine, tmp_path):
    seq = engine.messages.latest_seq
    engine.submit("save", name="../outside")
    wait(lambda: last_message(engine, seq))
    assert "plain name" in last_message(engine, seq)[-1][1]
    assert not (tmp_path.parent / "outside.h5").exists() and list(tmp_path.iterdir()) == []
    engine.submit("load", name="missing.h5")
    wait(lambda: len(last_message(engine, seq)) == 2)
    level, text = last_message(engine, seq)[-1]
    assert level == "error" and "missing.h5" in text
    assert engine.status()["preset"] == "ratchet16" and engine.status()["state"] == "running"


def test_a_lammps_packing_in_the_data_folder_replays_with_its_contacts_and_is_analysed(engine, tmp_path):
    """Load and replay takes another code's packing: a LAMMPS dump with the dump local of its
    contacts beside it (STEM-contacts.dump) shows its frames, timed by their timesteps, with
    LAMMPS's forces in the scene and z per frame; the status analysis uses those forces."""
    from tests.test_foreign_files import CONTACTS, PACKING, XYZ

    (tmp_path / "jammed.dump").write_bytes(PACKING.read_bytes())
    (tmp_path / "jammed-contacts.dump").write_bytes(CONTACTS.read_bytes())
    (tmp_path / "jammed.xyz").write_bytes(XYZ.read_bytes())
    assert {"jammed.dump", "jammed.xyz"} <= set(engine.saved_files())
    assert "jammed-contacts.dump" not in engine.saved_files()
    engine.submit("load", name="jammed.dump")
    status = wait(lambda: engine.status() if engine.status()["preset"] == "replay:jammed.dump" else None)
    assert status["replay"]["frames"] == 3 and status["replay"]["plot"] == "replay-structure"
    assert (status["replay"]["start"], status["replay"]["end"]) == (1337000.0, 1339000.0)
    assert status["particles"] == 200
    _, _, columns = engine.series("replay", Cursor())
    assert columns["z"][0] == pytest.approx(4.13)
    frame = wait(lambda: engine.frame(timeout=1.0)[1])
    assert frame.positions.shape == (200, 2) and frame.cell is not None
    assert len(frame.contact_force) == 413 and np.all(frame.contact_force > 0)  # LAMMPS's forces
    engine.submit("pause")
    engine.submit("analyze", kind="status")
    result = wait(lambda: engine.analysis.latest() if engine.analysis.latest().seq == 1 else None)
    assert result.error == "" and result.state.forces_known and result.report.values["contacts"] == 413
    engine.submit("load", name="jammed.xyz")
    status = wait(lambda: engine.status() if engine.status()["preset"] == "replay:jammed.xyz" else None)
    assert status["replay"]["frames"] == 1 and status["particles"] == 200


def test_an_analysis_runs_on_its_own_thread_on_the_state_of_that_moment(engine):
    """The status analysis of the running box: the engine keeps stepping while it runs, the
    result is the analysis of the state taken when the command arrived, and the plot data
    follow from it (one segment per contact, a marker per critical contact)."""
    from granlab.app.lab.analysis import mechanism_arrows, network_segments
    from granlab.engine.analysis.report import analyze

    wait(lambda: engine.status()["stage"] == "cycling")  # compressed: the disks touch
    engine.submit("analyze", kind="status")
    result = wait(lambda: engine.analysis.latest() if engine.analysis.latest().seq == 1 else None)
    assert result.error == "" and result.kind == "status"
    wait(lambda: engine.status()["time"] > result.state.time)  # the engine went on
    again = analyze(result.state, "status")
    assert again.values == result.report.values
    plots = network_segments(result)
    assert len(plots["segments"]["x0"]) == result.report.values["contacts"]
    assert len(plots["critical"]["x"]) == result.report.values["critical_contacts"]
    engine.submit("analyze", kind="stiffness")
    result = wait(lambda: engine.analysis.latest() if engine.analysis.latest().seq == 2 else None)
    arrows = mechanism_arrows(result)
    assert arrows.shape[1:] == (2, 2) and len(arrows) % 3 == 0
    assert (len(arrows) > 0) == (result.report.values["null_modes"] > 0)
    engine.submit("analyze", kind="volume")
    wait(lambda: any("analysis = volume is not allowed" in text for _, text in last_message(engine)))


def test_the_frames_kept_for_a_save_hold_to_their_memory_limit(tmp_path):
    lab = LabEngine(tmp_path, preset="ratchet16", speed=math.inf, history_mib=0.05)
    lab.start()
    try:
        wait(lambda: lab.status()["history_frames"] > 3 and lab.status()["step"] > 20000)
        frames = list(lab._history)
        held = sum(snap.nbytes for snap, _, _ in frames)
        assert held <= 0.05 * 2 ** 20 and held + frames[0][0].nbytes > 0.05 * 2 ** 20 * 0.9
        assert lab.status()["history_mib"] == pytest.approx(held / 2 ** 20)
    finally:
        lab.stop()


def test_the_lab_runs_at_the_chosen_speed_in_load_cycles_per_second(tmp_path):
    """Simulated time follows the wall clock at the chosen speed (here 0.5 load cycles of T = 10
    per second): the speed control is in simulated units, not steps."""
    lab = LabEngine(tmp_path, preset="ratchet16", speed=0.5)
    lab.start()
    try:
        wait(lambda: lab.status()["time"] > 1.0)
        t0, wall0 = lab.status()["time"], time.perf_counter()
        time.sleep(3.0)
        rate = (lab.status()["time"] - t0) / (time.perf_counter() - wall0)
        assert rate == pytest.approx(0.5 * 10.0, rel=0.2)
        assert lab.status()["speed_achieved"] == pytest.approx(0.5, rel=0.2)
    finally:
        lab.stop()


def test_a_lab_waiting_for_its_first_tab_starts_the_preset_at_t0(tmp_path):
    lab = LabEngine(tmp_path, preset="ratchet16", wait_for_tab=True)
    lab.start()
    try:
        time.sleep(0.5)
        assert lab.status()["state"] == "waiting" and lab.status()["step"] == 0
        lab.submit("tab_opened")
        wait(lambda: lab.status()["state"] == "running" and lab.status()["step"] > 0)
        assert lab.status()["time"] < 5.0  # from t = 0, not from where a warm-up left it
    finally:
        lab.stop()


def test_a_run_left_with_no_page_pauses_says_why_and_goes_on_when_a_page_opens(tmp_path, caplog):
    lab = LabEngine(tmp_path, preset="ratchet16", wait_for_tab=True, pause_without_pages=0.5)
    lab.start()
    try:
        lab.tabs = 1
        lab.submit("tab_opened")
        wait(lambda: lab.status()["state"] == "running" and lab.status()["step"] > 0)
        lab.tabs = 2
        lab.submit("tab_opened")
        lab.tabs = 1
        lab.submit("tab_closed")
        time.sleep(1.0)  # one page still open: twice the pause and the run goes on
        assert lab.status()["state"] == "running" and lab.status()["paused_for"] == ""
        with caplog.at_level("INFO", logger="granlab.lab"):
            lab.tabs = 0
            lab.submit("tab_closed")
            status = wait(lambda: lab.status()["state"] == "paused" and lab.status())
        assert status["paused_for"] == "no page open for 0.5 s"
        assert "no page open for 0.5 s: the run is paused; it goes on when a page opens" in caplog.messages
        step = status["step"]
        time.sleep(0.3)
        assert lab.status()["step"] == step
        lab.tabs = 1
        lab.submit("tab_opened")
        wait(lambda: lab.status()["state"] == "running" and lab.status()["step"] > step)
        assert lab.status()["paused_for"] == "" and lab.status()["time"] > status["time"]  # not restarted
        lab.submit("pause")  # paused by hand, the page closed, and opened again: it stays paused
        lab.tabs = 0
        lab.submit("tab_closed")
        time.sleep(1.0)
        lab.tabs = 1
        lab.submit("tab_opened")
        time.sleep(0.3)
        assert lab.status()["state"] == "paused" and lab.status()["paused_for"] == ""
    finally:
        lab.stop()


def test_record_writes_a_movie_of_the_last_simulated_seconds_into_the_data_folder(engine, tmp_path):
    import imageio.v3 as iio

    wait(lambda: engine.status()["time"] > 12.0)
    seq = engine.messages.latest_seq
    engine.submit("record", name="last-cycle.gif", seconds=10.0)  # 10 frames per cycle of T = 10
    engine.submit("record", name="by-pressure.gif", seconds=10.0, color="pressure")
    wait(lambda: len(last_message(engine, seq)) == 2)
    assert "recording last-cycle.gif is still going" in last_message(engine, seq)[-1][1]  # one movie at a time
    wait(lambda: (tmp_path / "last-cycle.gif").exists(), timeout=120.0)
    wait(lambda: not engine.status()["jobs"])
    engine.submit("record", name="by-pressure.gif", seconds=10.0, color="pressure")
    wait(lambda: (tmp_path / "by-pressure.gif").exists(), timeout=120.0)
    frames = iio.imread(tmp_path / "last-cycle.gif", index=None)
    assert 10 <= len(frames) <= 12 and frames.shape[1:3] == (720, 1280)
    by_pressure = iio.imread(tmp_path / "by-pressure.gif", index=None)
    # recorded one after the other (one movie at a time): the last 10 of simulated time, a frame more or less
    assert 10 <= len(by_pressure) <= 12 and by_pressure.shape[1:] == frames.shape[1:]
    assert not np.array_equal(by_pressure[0], frames[0])
    assert [m.text for m in engine.messages.since(0) if m.control == "record"][-1].startswith("recorded")
    seq = engine.messages.latest_seq
    engine.submit("record", name="movie.avi", seconds=10.0)
    wait(lambda: last_message(engine, seq))
    assert "a name ending in .gif or .mp4" in last_message(engine, seq)[-1][1]
    seq = engine.messages.latest_seq
    engine.submit("record", name="movie.gif", seconds=10.0, color="velocity")
    wait(lambda: last_message(engine, seq))
    assert "one of rotation, coordination, pressure, sliding" in last_message(engine, seq)[-1][1]


def test_a_number_of_disks_the_preset_cannot_use_is_refused_and_the_run_goes_on(engine):
    seq = engine.messages.latest_seq
    step = engine.status()["step"]
    engine.submit("apply", changes={"particles": 2, "seed": 0})
    wait(lambda: last_message(engine, seq))
    message = engine.messages.since(seq)[-1]
    assert message.control == "particles"
    assert message.text == "Disks N = 2 is not allowed: 4 to 20000 disks for the ratchet16 preset"
    assert engine.status()["particles"] == 16
    wait(lambda: engine.status()["step"] > step)


def test_reset_settings_restarts_with_the_presets_own_values_and_a_link_sets_up_once(engine):
    engine.submit("apply", changes={"friction": 0.6, "tangential_model": "angle"})
    wait(lambda: engine.status()["settings"]["friction"] == 0.6)
    seq = engine.messages.latest_seq
    engine.submit("defaults")
    wait(lambda: engine.status()["settings"]["tangential_model"] == "cundall-strack")
    s = engine.status()
    assert s["settings"]["friction"] == 0.2 and s["settings"]["speed"] == 0.5 and s["time"] < 5.0
    assert ("info", "the settings of ratchet16 are its own again (restarted at t = 0)") in last_message(engine, seq)
    assert s["link"] == {"preset": "ratchet16", "speed": "normal"}

    engine.submit("setup", name="block", changes={"friction": 0.3, "speed": 2.0})
    wait(lambda: engine.status()["preset"] == "block")
    wait(lambda: engine.status()["time"] > 1.0)
    s = engine.status()
    assert s["settings"]["friction"] == 0.3 and s["link"] == {"preset": "block", "friction": "0.3", "speed": "fast"}
    # the same setup again (a tab reopened on the link) does not restart; only its speed may change
    engine.submit("setup", name="block", changes={"friction": 0.3, "speed": 0.2})
    wait(lambda: engine.status()["settings"]["speed"] == 0.2)
    assert engine.status()["time"] >= s["time"]
    seq = engine.messages.latest_seq
    engine.submit("setup", name="block", changes={"friction": -1.0})
    wait(lambda: engine.messages.latest_seq > seq)
    assert last_message(engine, seq)[0][0] == "error" and engine.status()["settings"]["friction"] == 0.3


def test_the_live_text_says_the_state_and_the_scene_in_words():
    from granlab.app.lab.live import describe

    status = {"title": "Compression of a gas", "stage": "equilibrated", "state": "paused", "time": 212.5,
              "readout": {"phi": 0.8251, "z": 3.452, "sliding": 1}}
    scene = {"disks": 300, "walls": 0, "cell": [1.0, 0.0, 0.0, 1.0], "color_field": "coordination", "contacts": 517,
             "watched": 0}
    assert describe(status, scene) == (
        "Compression of a gas: equilibrated, paused, time 212.5; packing fraction 0.825; 3.45 contacts per disk; "
        "1 contact sliding. The scene shows 300 disks in a periodic cell, each coloured by its number of contacts; "
        "517 contacts drawn as lines as thick as their force.")
    status = {"title": "Ratcheting", "stage": "cycling", "state": "running", "time": 96.8, "cycle": 7,
              "strain": {"dgamma": 5.07e-8, "ratcheting": True}, "readout": {}}
    assert describe(status, {"disks": 0}) == ("Ratcheting: cycling, running, time 96.8, cycle 7; strain change per "
                                              "cycle 5.07×10⁻⁸, ratcheting.")
