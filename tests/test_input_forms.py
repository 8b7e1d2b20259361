"""A user's own files in forms kalmix does not read as they are (gzip on stdin, UTF-16 without a byte order mark)
stop with an error that says what they look like and how to convert them; the --rejects file and the ids of a
Parquet binary column are written as the main output is."""

import gzip
import io

import numpy as np
import pandas as pd
import pytest

from cli_helpers import invoke as _run

FAST = ["--experts", "2", "--seed", "1", "--no-progress", "--length-unit", "0.5"]


def _text(n=20):
    return "id,t,x,y\n" + "".join(f"{'ab'[k % 2]},{k // 2},{k * 0.5},{k * 0.25}\n" for k in range(n))


def test_gzip_on_stdin_says_to_decompress_it(cli):
    """Before: "the header holds bytes that are not UTF-8, b'\\x1f\\x8b...' (... if they are Latin-1); convert the
    input to UTF-8 first (... | iconv -f latin1 ...)", advice that cannot work on compressed data."""
    result = _run(cli, ["predict", "-", *FAST], input=gzip.compress(_text().encode()))
    assert result.exit_code == 1 and "iconv" not in result.stderr
    assert ("line 1: the input looks gzip-compressed (it starts with the bytes 1f 8b); decompress it first (zcat "
            "FILE | kalmix predict -), or pass the .gz file's path, which kalmix reads directly") in result.stderr


@pytest.mark.parametrize("encoding", ["utf-16le", "utf-16be"])
def test_utf16_without_a_byte_order_mark_says_how_to_convert_it(cli, tmp_path, encoding):
    """Before: "Could not detect position columns ...; available columns: ['i\\x00d\\x00', '\\x00t\\x00', ...]"
    (every other byte a zero, read as UTF-8). The file, its .gz and stdin name the encoding, and the command
    named converts it."""
    data = _text().encode(encoding)
    path, packed = tmp_path / "wide.csv", tmp_path / "wide.csv.gz"
    path.write_bytes(data)
    packed.write_bytes(gzip.compress(data))
    label = encoding.upper()
    for given, command in ((path, f"iconv -f {encoding} -t utf-8 {path} > {tmp_path / 'wide-utf8.csv'}"),
                           (packed, f"gunzip -c {packed} | iconv -f {encoding} -t utf-8 > "
                                    f"{tmp_path / 'wide-utf8.csv'}")):
        result = _run(cli, ["predict", str(given), *FAST])
        assert result.exit_code == 1 and "Could not detect" not in result.stderr
        assert (f"The track file {str(given)!r} is not UTF-8 text: line 1: it looks like {label} text without a byte "
                f"order mark (every other byte is zero). Convert it to UTF-8 first: {command}") in result.stderr
    piped = _run(cli, ["predict", "-", *FAST], input=data)
    assert piped.exit_code == 1 and (f"line 1: the input looks like {label} text without a byte order mark (every "
                                     f"other byte is zero); convert the input to UTF-8 first (... | iconv -f "
                                     f"{encoding} -t utf-8 | kalmix predict -)") in piped.stderr
    converted = tmp_path / "converted.csv"
    converted.write_text(data.decode(encoding))
    assert _run(cli, ["predict", str(converted), *FAST]).exit_code == 0


def test_utf16_is_told_by_a_zero_in_every_other_byte():
    """UTF-16 of Latin text (a zero high byte in every character); not of other scripts, nor binary data."""
    from kalmix.io.values import utf16_without_bom

    assert utf16_without_bom("id,t,x,y\n".encode("utf-16le")) == "utf-16le"
    assert utf16_without_bom("id,t,x,y\n".encode("utf-16be")) == "utf-16be"
    assert utf16_without_bom("id,t,x,y\n".encode()) is None
    assert utf16_without_bom("\u4e2d,\u6587\n".encode("utf-16le")) is None   # (Chinese: few zero bytes)
    assert utf16_without_bom(bytes(range(256)) * 4) is None   # zeros at one parity only, too few
    assert utf16_without_bom(b"\0" * 64) is None   # zeros in both parities


def test_the_rejects_file_ends_its_lines_as_the_output_does(cli, tmp_path):
    """Before: csv's default "\\r\\n" line ends in the --rejects file, "\\n" in the output."""
    lines = _text().splitlines()
    lines[5] = "a,2,oops,1"
    path, rejects, out = tmp_path / "t.csv", tmp_path / "rejects.csv", tmp_path / "out.csv"
    path.write_text("\n".join(lines) + "\n")
    result = _run(cli, ["predict", str(path), *FAST, "--rejects", str(rejects), "-o", str(out)])
    assert result.exit_code == 0, result.stderr
    written = rejects.read_bytes()
    assert b"\r" not in written and b"\r" not in out.read_bytes()
    assert written.decode() == "line,reason,input\n6,\"column 'x' must hold a number, got 'oops'\",\"a,2,oops,1\"\n"


def test_binary_ids_of_a_parquet_file_are_text_in_csv_output(cli, tmp_path):
    """Before: a Parquet id column of bytes came out as Python's b'a' in CSV (JSON lines wrote a). Ids that are
    UTF-8 are their text, as the same file with text ids gives, bytes that are not as JSON lines write them
    (\\xe9); the Parquet output keeps the bytes."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pd.read_csv(io.StringIO(_text()))
    text = tmp_path / "text.parquet"
    table.to_parquet(text, index=False)
    binary = tmp_path / "binary.parquet"
    pq.write_table(pa.table({"id": pa.array([v.encode() for v in table["id"]], pa.binary()),
                             **{name: table[name] for name in ("t", "x", "y")}}), binary)
    for args in ([], ["--chunk-rows", "3"]):
        said = _run(cli, ["predict", str(binary), *FAST, *args])
        assert said.exit_code == 0 and "b'" not in said.stdout
        assert said.stdout == _run(cli, ["predict", str(text), *FAST, *args]).stdout
    odd = tmp_path / "odd.parquet"
    pq.write_table(pa.table({"id": pa.array([b"\xe9t\xe9" if v == "a" else b"b" for v in table["id"]]),
                             **{name: table[name] for name in ("t", "x", "y")}}), odd)
    csv_out, jsonl_out = tmp_path / "out.csv", tmp_path / "out.jsonl"
    for out in (csv_out, jsonl_out):
        assert _run(cli, ["predict", str(odd), *FAST, "-o", str(out)]).exit_code == 0
    ids = pd.read_csv(csv_out, dtype={"id": str})["id"]
    assert ids.tolist() == ["\\xe9t\\xe9", "b"] * 10
    assert pd.read_json(jsonl_out, lines=True, dtype={"id": str})["id"].tolist() == ids.tolist()
    parquet_out = tmp_path / "out.parquet"
    assert _run(cli, ["predict", str(odd), *FAST, "-o", str(parquet_out)]).exit_code == 0
    kept = pq.read_table(parquet_out)
    assert kept.schema.field("id").type == pa.binary()
    assert kept.column("id").to_pylist() == [b"\xe9t\xe9", b"b"] * 10
    assert np.isfinite(pd.read_csv(csv_out)["pred_x"].iloc[2:]).all()
    from kalmix.commands._output import csv_text

    frame = pd.DataFrame({"track_id": [b"ab", None, b"\xe9"], "x": [1.0, 2.0, 3.0]})
    assert csv_text(frame, header=True) == "track_id,x\nab,1.0\n,2.0\n\\xe9,3.0\n"
