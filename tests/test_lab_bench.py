"""``granlab bench --lab --viewers N``: the classroom's report, from a short run (3 viewers, 256 disks).
Only its structure and that every page received something are checked: its timings depend on the
machine."""

import json

from granlab.app import commands as cli
from granlab.app.lab import bench


def test_the_classroom_bench_reports_what_each_page_received(capsys):
    code = cli.main(["bench", "--lab", "--viewers", "3", "--particles", "256", "--seconds", "2", "--json"])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    report = json.loads(printed.out)
    assert report["viewers"] == 3 and report["targets"] == bench.CLASSROOM_TARGETS
    [run] = report["runs"]
    assert run["particles"] == 256 and len(run["viewers"]) == 3 and run["tabs"] == 4
    for page in [run["presenter"], *run["viewers"]]:
        assert page["scene"]["frames"] > 0 and page["scene"]["bytes"] > 0, page
        assert page["bokeh"]["messages"] > 0 and page["bokeh"]["bytes"] > 0, page
    assert set(run["per_viewer"]) == {"frames_per_s", "scene_messages_per_s", "scene_bytes_per_s",
                                      "bokeh_messages_per_s", "bokeh_bytes_per_s", "mbit_per_s"}
    assert all(set(spread) == {"min", "median", "max"} for spread in run["per_viewer"].values())
    assert len(run["latency_ms"]) == len(run["command_ms"]) == run["commands_sent"] - run["commands_lost"]
    assert run["commands_sent"] >= 1
    assert run["engine_share"] > 0 and run["headless_same_interval"] > 0
    assert run["memory_peak_mib"] >= run["memory_idle_mib"] > 0
    # viewer 1's bytes sorted by what carried them: the viewers' stream, frames' changes (and key frames)
    assert "viewers' stream, changes" in run["anatomy"]["scene"]
    assert set(run["anatomy"]["scene"]) <= {"viewers' stream, key frames", "viewers' stream, changes"}
    assert run["anatomy"]["bokeh"]
    assert set(run["pass"]) == {"frames", "latency", "engine", "bandwidth"}
    bench.print_classroom(report)
    assert "256 disks" in capsys.readouterr().out


def test_viewers_go_with_lab(capsys):
    assert cli.main(["bench", "--viewers", "3"]) == 2
    assert "--viewers goes with --lab" in capsys.readouterr().err
