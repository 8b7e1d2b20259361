"""A user's own files in forms kalmix does not read as they are (gzip on stdin, UTF-16 without a byte order mark)
stop with an error that says what they look like and how to convert them; the --rejects file and the ids of a
Parquet binary column are written as the main output is."""

import gzip

import pytest
from click.testing import CliRunner

from kalmix.cli import build

FAST = ["--experts", "2", "--seed", "1", "--no-progress", "--length-unit", "0.5"]


@pytest.fixture(scope="module")
def cli():
    return build()


def _run(cli, args, input=None):
    return CliRunner().invoke(cli, args, input=input, catch_exceptions=False)


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
