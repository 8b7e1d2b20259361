"""The README's Python examples run as written."""

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_python_block_runs(index, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(BLOCKS[index], f"README block {index}", "exec"), {})


def test_readme_opens_with_the_two_setup_commands():
    first_block = re.search(r"```bash\n(.*?)```", README.read_text(), flags=re.S).group(1).strip().splitlines()
    assert len(first_block) == 2
    assert "pip install" in first_block[0] and "kalmix" in first_block[0]
    assert "pip install \".[test]\"" in first_block[1] and "pytest" in first_block[1]
    assert first_block[1].split("&&", 1)[1].strip() in (Path(README.parent, ".ci/run").read_text())


def test_readme_python_is_the_quickstart_example():
    """The README shows examples/quickstart.py as it is (the docs include the file; tests/test_examples.py runs it)."""
    quickstart = (README.parent / "examples" / "quickstart.py").read_text()
    assert BLOCKS == [quickstart]


def test_readme_is_a_page_a_person_reads():
    """The README stays short: the details live in docs/, history in CHANGELOG.md."""
    text = README.read_text()
    assert len(text.splitlines()) <= 250
    assert not re.search(r"<!-- (?!--8<-- \[(start|end):)", text)   # no placeholder left (snippet markers aside)
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text)        # no dated prose


def test_readme_results_table_is_generated():
    """The README's table of what to expect is `python -m benchmarks.results_tables --headline`, not typed by hand."""
    import sys

    sys.path.insert(0, str(README.parent))
    from benchmarks.results_tables import Results, headline

    table = "\n\n".join(t.markdown() for t in headline(Results()))
    assert table.strip() in README.read_text()


def test_readme_predict_output_is_what_predict_prints(tmp_path):
    """The output the README shows for `kalmix predict examples/boats.csv` is what the command prints."""
    import subprocess
    import sys

    shown = re.search(r"\$ kalmix predict examples/boats.csv \| head -(\d+)\n(.*?)```", README.read_text(), flags=re.S)
    count, lines = int(shown.group(1)), shown.group(2).strip().splitlines()
    boats = str(README.parent / "examples" / "boats.csv")
    done = subprocess.run([sys.executable, "-m", "kalmix.cli", "predict", boats],
                          capture_output=True, text=True, cwd=tmp_path, timeout=900)
    assert done.returncode == 0, done.stderr
    assert lines == done.stdout.splitlines()[:count]
