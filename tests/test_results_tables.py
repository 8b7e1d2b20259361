"""The docs' Results page is generated from benchmarks/results/*.json: every file is shown or said not to be,
every marker of the page has tables, and no table is empty."""

import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks import results_tables as rt  # noqa: E402 (after the path is set)


def _tables(markdown: str):
    """Each markdown table of ``markdown`` as (header cells, data rows of cells)."""
    lines = markdown.splitlines()
    tables, i = [], 0
    while i < len(lines):
        if lines[i].lstrip().startswith("|") and i + 1 < len(lines) and re.match(r"^\s*\|[-:| ]+\|\s*$", lines[i + 1]):
            header = _cells(lines[i])
            j, rows = i + 2, []
            while j < len(lines) and lines[j].lstrip().startswith("|"):
                rows.append(_cells(lines[j]))
                j += 1
            tables.append((header, rows))
            i = j
        else:
            i += 1
    return tables


def _cells(line: str):
    return [c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]


@pytest.fixture(scope="module")
def page():
    results = rt.Results()
    return rt.page(results), results


def test_every_results_file_is_shown_or_listed_as_not_shown(page):
    _, results = page
    files = set(results.names())
    assert files, "no JSON in benchmarks/results"
    for name in rt.SECTIONS:   # every table, on the page or not
        rt.render(name, results)
    unread = files - results.read - set(rt.NOT_SHOWN)
    assert not unread, f"read by no table and not in NOT_SHOWN: {sorted(unread)}"
    assert not set(rt.NOT_SHOWN) - files, "NOT_SHOWN names a file that is not there"
    assert not set(rt.NOT_SHOWN) & results.read, "a file in NOT_SHOWN is shown"
    assert all(reason.strip() for reason in rt.NOT_SHOWN.values())


def test_the_page_uses_every_section_and_leaves_no_marker(page):
    text, _ = page
    markers = rt.MARKER.findall(rt.PAGE.read_text())
    names = [name for _, name in markers]
    assert sorted(set(names)) == sorted(rt.SECTIONS), "a section is missing from docs/results.md, or unknown there"
    assert not rt.MARKER.search(text) and "results:table" not in text


def test_the_generated_page_has_no_empty_table(page):
    text, _ = page
    tables = _tables(text)
    assert len(tables) >= len(rt.SECTIONS)
    for header, rows in tables:
        assert rows, f"table {header} has no rows"
        for row in rows:
            assert len(row) == len(header), (header, row)
            assert any(c not in ("", "—") for c in row[1:]), f"row {row} of table {header} holds no value"
        for column in range(1, len(header)):   # no column without a single figure
            assert any(row[column] not in ("", "—") for row in rows), f"column {header[column]!r} is empty"


def test_every_table_names_existing_sources_and_a_command(page):
    text, _ = page
    captions = re.findall(r"<small>From (.*?), written by ((?:`[^`]+`(?: and )?)+)\.", text)
    assert len(captions) == len(_tables(text))
    for files, commands in captions:
        names = re.findall(r"`benchmarks/results/([^`]+)`", files)
        assert names
        for name in names:
            assert (rt.RESULTS_DIR / name).is_file(), name
        for command in re.findall(r"`([^`]+)`", commands):
            assert command.startswith(("python -m benchmarks.", "kalmix evaluate")), command


def test_the_headline_compares_kalmix_with_the_best_tuned_peer_on_each_recording():
    results = rt.Results()
    (table,) = rt.headline(results)
    assert len(table.rows) == 2 * len(rt.RECORDINGS)
    lead = results("lead_vs_peers.json")
    for i, dataset in enumerate(rt.RECORDINGS):
        one, ahead = table.rows[2 * i], table.rows[2 * i + 1]
        assert one[0] == dataset and ahead[0] == ""
        evaluation = results(rt.evaluate_file(dataset))
        peers, _ = rt.one_step_peers(evaluation)
        assert peers and all(not name.startswith(rt.NOT_PEERS) for name in peers)
        mixture = evaluation["overall"]["mixture"]["one_step"]["rms"]
        best = min(peers, key=peers.get)   # beaten by no other peer scored on the same values
        assert one[2:] == [rt.num(mixture), rt._peer_name(best), rt.num(peers[best]), rt.ratio(mixture / peers[best])]
        assert ahead[1].startswith("10 ") and ahead[5] == rt.ratio(lead[dataset]["H=10"]["ratio"])


def test_a_peer_run_on_a_subsample_is_left_out_of_the_comparison():
    evaluation = {"predictors": ["mixture", "CV Kalman", "MMAE bank (filterpy, real dt)", "best expert (hindsight)"],
                  "overall": {"mixture": {"one_step": {"rms": 1.0, "count": 100}},
                              "CV Kalman": {"one_step": {"rms": 1.2, "count": 100}},
                              "MMAE bank (filterpy, real dt)": {"one_step": {"rms": 0.5, "count": 40}},
                              "best expert (hindsight)": {"one_step": {"rms": 0.9, "count": 100}}}}
    assert rt.best_one_step_peer(evaluation) == ("CV Kalman", 1.2)
    assert rt.one_step_peers(evaluation)[1] == ["MMAE bank (filterpy, real dt)"]


def test_not_peers_is_the_benchmarks_own_list():
    lead_vs_peers = pytest.importorskip("benchmarks.lead_vs_peers")
    assert rt.NOT_PEERS == lead_vs_peers.NOT_PEERS


def test_the_command_line_prints_the_headline_and_the_page(capsys):
    rt.main(["--headline"])
    out = capsys.readouterr().out
    assert sum(line.startswith("| ") for line in out.splitlines()) == 1 + 2 * len(rt.RECORDINGS)
    assert "best tuned peer" in out and "tuned on the first 20 %" in out
    rt.main([])
    assert "# Results" in capsys.readouterr().out
    rt.main(["--list"])
    assert capsys.readouterr().out.split() == list(rt.SECTIONS)


def test_bad_input_gives_clear_errors(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="unknown results table 'nope'; expected one of headline"):
        rt.fill("<!-- results:table nope -->")
    with pytest.raises(FileNotFoundError, match="lead_vs_peers.json: no such results file"):
        rt.render("lead", rt.Results(tmp_path))
    (tmp_path / "lead_vs_peers.json").write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        rt.render("lead", rt.Results(tmp_path))
    (tmp_path / "lead_vs_peers.json").write_text(json.dumps({name: {"H=2": {
        "mixture_rms": 1.0, "best_peer": "p", "best_peer_rms": 2.0, "ratio": 0.5}} for name in rt.RECORDINGS}))
    for name in rt.RECORDINGS:
        (tmp_path / rt.evaluate_file(name)).write_text(json.dumps({
            "predictors": ["mixture", "p"], "tuned": {"mixture": {"bank": {"time_unit": 1.0}}},
            "overall": {"mixture": {"one_step": {"rms": 1.0, "count": 1}},
                        "p": {"one_step": {"rms": 2.0, "count": 1}}}}))
    monkeypatch.setattr(rt, "RESULTS_DIR", tmp_path)
    with pytest.raises(SystemExit, match="lead_vs_peers.json has no H=10 for hawkeye_ball: it has H=2"):
        rt.main(["--headline"])


def test_an_indented_marker_gets_indented_tables():
    text = rt.fill("??? note\n    <!-- results:table lead -->\n")
    body = text.splitlines()[1:]
    assert body and all(line.startswith("    ") for line in body if line)


@pytest.mark.parametrize("value, digits, text", [
    (0.019130424, 4, "0.01913"), (1.30822, 4, "1.308"), (50851.13, 3, "50,851"), (7007691.9, 3, "7.01e6"),
    (8.1507e-13, 2, "8.2e-13"), (float("nan"), 4, "—"), (None, 4, "—"), (0.0, 4, "0"), (32.295, 4, "32.30"),
])
def test_numbers_are_written_plainly(value, digits, text):
    assert rt.num(value, digits) == text
