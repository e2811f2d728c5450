"""The COLMAP text pre-check's fast path (colmap.FAST_LINES) decides exactly as the per-token check: it takes only
lines that check passes, so on many generated lines, valid and subtly not, the errors are the same with and without
it. The per-token check's own verdicts on odd input (tables below) are pinned."""

from __future__ import annotations

import random
import re
from pathlib import Path

import pycolmap
import pytest

from splatu.data import colmap
from tests.benchmark_scripts import benchmark_script

NUMBERS = ["0", "-1", "1.5", "4.8222974381749717", "-0.0336422", "207.398", "1e-05", "1.2345678901234567e-05",
           "-2.5e+20", "12345678901234567890", "123456789012345678901234567890", "5.", "0.000012345678901234567890123"]
ODD_NUMBERS = ["1e999", "9" * 400, "1e+99", "9" * 50 + "e+99", "1e308", "1e309", "nan", "NaN", "inf", "-inf",
               "Infinity", ".5", "+5", "1_0", "1__0", "1E+05", "1e5", "1.5.2", "1e5e5", "-", "e5", "0x10", "x",
               "１", "٣", "٣.٥", "5e-5", "1e-100", "1e+999", "1e+309", "1.7e+308", "1e-999"]
IDS = ["0", "1", "7", "1234", "999999999", "4294967294", "18446744073709551614"]
ODD_IDS = ["-0", "+3", "007", "1.5", "-1", "1e3", "4294967295", "4294967296", "1000000000", "18446744073709551615",
           "99999999999999999999", "１", "٣", "1_0", "nan", "x"]
POINT3D_REFS = ["-1", "0", "7", "2749", "999999999999999999"]
ODD_POINT3D_REFS = ["1.5", "7.0", "1e3", "-2", "+7", "007", "9223372036854775807", "9223372036854775808",
                    "99999999999999999999", "-9223372036854775809", "nan", "x"]
CHANNELS = ["0", "9", "10", "99", "100", "199", "200", "249", "250", "255"]
ODD_CHANNELS = ["256", "300", "-1", "007", "0255", "+5", "1.0", "1e2", "٢٥٥", "２５５", "nan", "99999999"]
NAMES = ["a.png", "IMG_0001.JPG", "dir/x.jpg", "5", "#x", "é.png", "my photo.jpg", "a\u00a0b.png", "a\x1cb.png"]
SEPARATORS = [" "] * 12 + ["  ", "\t", " \t", "\u00a0", "\x0b", "\x1c", "\u3000"]
ENDINGS = ["\n"] * 8 + ["\r\n", "\r", " \n", "\t\n", "  \r\n"]
PREFIXES = [""] * 20 + [" ", "\t", "# ", "  # ", "\ufeff"]


class Lines:
    """Random lines of each kind: fields as COLMAP writes them, else (at rate `odd`) an odd one; joined by single
    spaces with LF or CRLF, else (at rate `messy`) by whitespace of other kinds, indented, commented, a lone CR."""

    def __init__(self, seed: int, odd: float = 0.04, messy: float = 0.5) -> None:
        self.rng, self.odd, self.messy = random.Random(seed), odd, messy

    def pick(self, usual: list[str], odd: list[str]) -> str:
        return self.rng.choice(odd if self.rng.random() < self.odd else usual)

    def join(self, fields: list[str]) -> str:
        rng = self.rng
        if rng.random() >= self.messy:
            return " ".join(fields) + rng.choice(["\n", "\r\n"])
        text = rng.choice(PREFIXES) + "".join(field + rng.choice(SEPARATORS) for field in fields[:-1])
        return text + (fields[-1] if fields else "") + rng.choice(ENDINGS)

    def point(self) -> str:
        track = [self.pick(IDS[:5], ODD_IDS) for _ in range(2 * self.rng.randint(0, 6))]
        if self.rng.random() < self.odd:  # an odd track length
            track.append(self.pick(IDS[:5], ODD_IDS))
        return self.join([self.pick(IDS, ODD_IDS), *(self.pick(NUMBERS, ODD_NUMBERS) for _ in range(3)),
                          *(self.pick(CHANNELS, ODD_CHANNELS) for _ in range(3)), self.pick(NUMBERS, ODD_NUMBERS),
                          *track])

    def pose(self) -> str:
        fields = [self.pick(IDS[:5], ODD_IDS), *(self.pick(NUMBERS, ODD_NUMBERS) for _ in range(7)),
                  self.pick(IDS[:5], ODD_IDS), self.rng.choice(NAMES)]
        return self.join(fields[:self.rng.randint(8, 10)] if self.rng.random() < self.odd else fields)

    def points2d(self) -> str:
        count = 3 * self.rng.randint(0, 5) + (self.rng.choice([-1, 1]) if self.rng.random() < self.odd else 0)
        return self.join([self.pick(POINT3D_REFS, ODD_POINT3D_REFS) if i % 3 == 2 else self.pick(NUMBERS, ODD_NUMBERS)
                          for i in range(max(count, 0))])


def write_lines(path: Path, lines: list[str], extra: bytes = b"") -> Path:
    path.write_bytes("".join(lines).encode("utf-8") + extra)
    return path


def slow_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """Send every line to the per-token check, as before the fast path."""
    never = re.compile(r"(?!)")
    monkeypatch.setattr(colmap, "FAST_LINES", dict.fromkeys(colmap.FAST_LINES, never))


def shown(error: Exception | None) -> str | None:
    return None if error is None else str(error)


def two_pass_layout(path: Path) -> tuple[int | None, tuple[int, str] | None]:
    """The images.txt layout faults as found before the one pass: the first pose line where the reader expects the
    line before's 2D points, by following the reader; the first pose line with more than 10 fields."""
    pose_after_pose, expect_points = None, False
    for number, text in colmap._numbered_lines(path):
        if expect_points:
            if colmap._is_pose(text.split()):
                pose_after_pose = number
                break
            expect_points = False
        elif not text.startswith("#"):
            expect_points = colmap._is_pose(text.split())
    spaced = next(((number, " ".join(tokens[9:])) for number, tokens in colmap._data_lines(path)
                   if len(tokens) > 10 and colmap._is_pose(tokens)), None)
    return pose_after_pose, spaced


@pytest.mark.parametrize("seed", range(4))
def test_each_line_the_fast_path_takes_is_one_the_per_token_check_passes(tmp_path, seed):
    lines = Lines(seed)
    kinds = {"points3D": lines.point, "pose": lines.pose, "points2D": lines.points2d}
    taken = refused = 0
    for kind, make in kinds.items():
        path = write_lines(tmp_path / f"{kind}.txt", [make() for _ in range(3000)])
        file = "points3D" if kind == "points3D" else "images"
        for number, text in colmap._numbered_lines(path):
            tokens, error = colmap._line_error(path, file, number, text)
            valid = bool(tokens) and not tokens[0].startswith("#") and error is None
            refused += not valid
            if colmap.FAST_LINES[kind].fullmatch(text):
                taken += 1
                assert valid, text
                if file == "images":  # a pose line, with no space in its name; a points line, no pose line
                    assert colmap._is_pose(tokens) == (kind == "pose") and (kind != "pose" or len(tokens) == 10), text
    assert taken > 1500 and refused > 1500  # both kinds of line were there in numbers


@pytest.mark.parametrize("seed", range(60))
def test_a_generated_model_gets_the_same_verdict_with_and_without_the_fast_path(tmp_path, monkeypatch, seed):
    """Whole files, so line numbering (CRLF, a lone CR, bytes that are no UTF-8) and the images.txt layout checks
    (a pose after a pose, a name with a space) are compared too; those also with the two passes they once took."""
    rng = random.Random(seed)
    lines = Lines(seed, odd=rng.choice([0.0, 0.002, 0.01]), messy=rng.choice([0.0, 0.01, 0.1]))
    images = []
    for _ in range(rng.randint(1, 6)):
        images.append(lines.pose())
        if rng.random() < 0.9:  # else the points line is left out: a pose after a pose
            images.append(lines.points2d() if rng.random() < 0.8 else "\n")
    files = {"cameras": write_lines(tmp_path / "cameras.txt", ["# cameras\n", "1 PINHOLE 8 6 5 5 4 3\n"]),
             "images": write_lines(tmp_path / "images.txt", ["# images\n", *images],
                                   b"\xff\n" if rng.random() < 0.1 else b""),
             "points3D": write_lines(tmp_path / "points3D.txt", [lines.point() for _ in range(30)])}
    fast = tuple(map(shown, colmap.text_model_errors(files)))
    if fast[0] is None:
        assert fast[1] == shown(colmap._layout_error(files["images"], *two_pass_layout(files["images"])))
    slow_only(monkeypatch)
    assert fast == tuple(map(shown, colmap.text_model_errors(files)))


def test_lines_as_colmap_writes_them_take_the_fast_path():
    """The speed-up holds only while real lines match (lund_door's, and an exponent as %.17g writes one)."""
    assert colmap.FAST_LINES["points3D"].fullmatch(
        "11686 5.528041511827797 5.4739093221374002 17.951171205614333 134 128 132 0.38821204521741998 2 7379 1 7367\n")
    assert colmap.FAST_LINES["points3D"].fullmatch("3 -1.2345678901234567e-05 0 1 255 0 9 1e-05\n")
    assert colmap.FAST_LINES["pose"].fullmatch(
        "1 0.983789 0.00113517 0.176825 -0.0298644 -7.60712 0.428157 2.75243 1 DSC_0001.JPG\n")
    assert colmap.FAST_LINES["points2D"].fullmatch("207.398 25.1136 -1 721.026 26.3628 2749\n")
    for kind, line in [("points3D", "3 0.5 0 1 255 0 9 0.1 1 2"), ("pose", "1 1 0 0 0 0 0 1 1 a.png"),
                       ("points2D", "207.398 25.1136 -1")]:  # a CRLF file's lines too, a lone CR's never
        assert colmap.FAST_LINES[kind].fullmatch(line + "\r\n") and not colmap.FAST_LINES[kind].fullmatch(line + "\r")


@pytest.mark.parametrize(("text", "verdict"), [
    ("7 0.5 0.5 2 255 0 0 0.1 1 2\r\n", None),
    ("7\t0.5\t0.5\t2\t255\t0\t0\t0.1\t1\t2  \n", None),  # tabs and trailing spaces are whitespace to split()
    ("  # an indented comment\n", None),
    ("１ 0.5 0.5 2 ٢٥٥ 0 0 0.1 1 2\n", "cannot parse points3D.txt line 1 ('１ 0.5 0.5 2 ٢٥٥ 0 0 0.1 1 2')"),  # Python's
    ("7 1_0.5 0.5 2 255 0 0 0.1 1 2\n", "cannot parse points3D.txt line 1 ('7 1_0.5 0.5 2 255 0 0 0.1 1 2')"),  # int()
    ("7 0.5 0.5 2 +255 0 0 0.1 1 2\n", None),  # reads other scripts' digits and underscores, COLMAP's a + sign alone
    ("7 0.5 0.5 2 255 0 0 0.1 4294967294 2\n", None),
    ("7 0.5 0.5 2 255 0 0 0.1 4294967295 2\n", "cannot parse points3D.txt line 1 ('7 0.5 0.5 2 255 0 0 0.1 4294967295 "
     "2')"),
    ("7 1e999 0.5 2 255 0 0 0.1\n", "cannot parse points3D.txt line 1 ('7 1e999 0.5 2 255 0 0 0.1')"),
    ("7 nan 0.5 2 255 0 0 0.1\n", "cannot parse points3D.txt line 1 ('7 nan 0.5 2 255 0 0 0.1')"),
    ("7 0.5 0.5 2 255 0 0 0.1 1\n", "cannot parse points3D.txt line 1 ('7 0.5 0.5 2 255 0 0 0.1 1')"),
    ("7.5 0.5 0.5 2 255 0 0 0.1\n", "cannot parse points3D.txt line 1 (POINT3D_ID 7.5 is not an id, a whole number "
     "from 0 to 18446744073709551614)"),
    ("-1 0.5 0.5 2 255 0 0 0.1\n", "cannot parse points3D.txt line 1 (POINT3D_ID -1 is not an id, a whole number "
     "from 0 to 18446744073709551614)"),
    ("# x\r7 0.5 0.5 2 256 0 0 0.1\n", "points3D.txt line 1 ends in a lone carriage return (CR), which COLMAP does "
     "not read as the end of a line"),  # to COLMAP one line, a comment
    ("7 0.5 0.5 2 255 0 0 0.1\r", "points3D.txt line 1 ends in a lone carriage return (CR), which COLMAP does not "
     "read as the end of a line"),
])
def test_the_per_token_checks_verdicts_on_odd_points3d_lines(tmp_path, text, verdict):
    files = {"cameras": write_lines(tmp_path / "cameras.txt", ["1 PINHOLE 8 6 5 5 4 3\n"]),
             "images": write_lines(tmp_path / "images.txt", ["1 1 0 0 0 0 0 1 1 a.png\n", "\n"]),
             "points3D": write_lines(tmp_path / "points3D.txt", [text])}
    error, layout = colmap.text_model_errors(files)
    assert (None if error is None else error.what) == verdict and layout is None


@pytest.fixture(scope="module")
def precheck_benchmark():
    yield from benchmark_script("colmap_precheck")


def test_the_benchmarks_model_is_one_pycolmap_reads_whole(tmp_path, precheck_benchmark):
    """Its tracks name the 2D points that name them back, so the timed read is of a model COLMAP would write."""
    files = precheck_benchmark.write_model(tmp_path, points=300, images=12)
    assert colmap.text_model_errors(files) == (None, None)
    model = pycolmap.Reconstruction(str(tmp_path))
    assert len(model.points3D) == 300 and len(model.images) == 12
    for point_id, point in model.points3D.items():
        assert 2 <= point.track.length() <= 10
        for element in point.track.elements:
            assert model.images[element.image_id].points2D[element.point2D_idx].point3D_id == point_id


@pytest.mark.parametrize(("faults", "first"), [
    ({"spaced"}, "images.txt line 6 names image 'my c.png'"),
    ({"spaced", "pose_after_pose"}, "images.txt line 3 is an image's pose where COLMAP reads the 2D points"),
    ({"spaced", "pose_after_pose", "no_camera"}, "image d.png uses camera 9, which cameras.txt does not define"),
    ({"spaced", "pose_after_pose", "no_camera", "parse"}, "cannot parse images.txt line 9 ('1 2 3 4')"),
])
def test_an_images_txt_with_several_faults_is_refused_for_the_one_checked_first(tmp_path, faults, first):
    """One pass finds them all; they are raised as when each had its pass: a line that does not parse, then what
    pycolmap cannot read, then a pose where 2D points belong, then a name with a space."""
    lines = ["# images\n", *(f"{i} 1 0 0 0 0 0 1 1 {name}.png\n\n" for i, name in enumerate("abcd", start=1))]
    lines = "".join(lines).splitlines(keepends=True)
    if "pose_after_pose" in faults:
        lines[2] = "5 1 0 0 0 0 0 1 1 e.png\n"
    if "spaced" in faults:
        lines[5] = "3 1 0 0 0 0 0 1 1 my c.png\n"
    if "no_camera" in faults:
        lines[7] = "4 1 0 0 0 0 0 1 9 d.png\n"
    if "parse" in faults:
        lines[8] = "1 2 3 4\n"
    write_lines(tmp_path / "cameras.txt", ["1 PINHOLE 8 6 5 5 4 3\n"])
    write_lines(tmp_path / "images.txt", lines)
    write_lines(tmp_path / "points3D.txt", [])
    with pytest.raises(colmap.SplatuError) as raised:
        colmap.read_reconstruction(tmp_path)
    assert raised.value.what.startswith(first)


def model(tmp_path: Path, images: str, points: str = "") -> dict[str, Path]:
    return {"cameras": write_lines(tmp_path / "cameras.txt", ["1 PINHOLE 8 6 5 5 4 3\n"]),
            "images": write_lines(tmp_path / "images.txt", [images]),
            "points3D": write_lines(tmp_path / "points3D.txt", [points])}


def pycolmap_refuses(folder: Path) -> bool:
    try:
        pycolmap.Reconstruction(str(folder))
    except (ValueError, IndexError, RuntimeError):
        return True
    return False


POSES = "1 1 0 0 0 0 0 1 1 a.png\n10 20 -1\n2 1 0 0 0 1 0 1 1 b.png\n\n"


@pytest.mark.parametrize(("images", "points", "what"), [
    # a no-break space, U+3000 and the like are whitespace to Python's str.split, part of a field to COLMAP's reader
    (POSES.replace("1 1 0", "1\u00a01 0"), "", "cannot parse images.txt line 1 ('1\\xa01 0 0 0 0 0 1 1 a.png')"),
    (POSES, "7\u30000.5 0.5 2 255 0 0 0.1\n", "cannot parse points3D.txt line 1 ('7\\u30000.5 0.5 2 255 0 0 0.1')"),
    (POSES, "\u00a0\n", "cannot parse points3D.txt line 1 ('\\xa0')"),
    (POSES, "\u00a0# an indented comment\n", "cannot parse points3D.txt line 1 ('\\xa0#"),
    # COLMAP's trim takes spaces, tabs, CR and LF: a line of \v or \f, or a comment after one, is data to it
    (POSES, "\v\n", "cannot parse points3D.txt line 1 ('\\x0b')"),
    (POSES, "\f# a comment\n", "cannot parse points3D.txt line 1 ('# a comment')"),
])
def test_a_line_pycolmap_refuses_naming_no_line_is_named(tmp_path, images, points, what):
    """These passed the check, as Python splits and trims a line at other characters than COLMAP's reader, and
    pycolmap's refusal named neither file nor line ("Check failed: line_stream >> point3D_id >> ...")."""
    files = model(tmp_path, images, points)
    assert pycolmap_refuses(tmp_path)
    error, _ = colmap.text_model_errors(files)
    assert error is not None and error.what.startswith(what)


@pytest.mark.parametrize(("images", "what"), [
    # the line right after a pose is its 2D points, whatever it holds: the points after a comment or blank line
    # there, or a second points line, are read as a pose
    ("1 1 0 0 0 0 0 1 1 a.png\n# its points\n10 20 -1\n2 1 0 0 0 1 0 1 1 b.png\n\n",
     "images.txt line 3 is not an image's pose"),
    ("1 1 0 0 0 0 0 1 1 a.png\n\n10 20 -1\n2 1 0 0 0 1 0 1 1 b.png\n\n", "images.txt line 3 is not an image's pose"),
    ("1 1 0 0 0 0 0 1 1 a.png\n10 20 -1\n10 20 -1\n", "images.txt line 3 is not an image's pose"),
    ("1 1 0 0 0 0 0 1 1 a.png\n\v\n\v\n", "images.txt line 3 is not an image's pose"),
    # a pose where the 2D points belong is the likelier cause of a points line where a pose belongs
    ("1 1 0 0 0 0 0 1 1 a.png\n2 1 0 0 0 1 0 1 1 b.png\n10 20 -1\n",
     "images.txt line 2 is an image's pose where COLMAP reads the 2D points of the image on the line before"),
])
def test_an_images_txt_line_where_colmap_reads_a_pose_but_finds_none_is_named(tmp_path, images, what):
    """These passed the check, and pycolmap's refusal named neither file nor line ("Check failed: line_stream1 >>
    image_id >> ...")."""
    files = model(tmp_path, images)
    assert pycolmap_refuses(tmp_path)
    error, _ = colmap.text_model_errors(files)
    assert error is not None and error.what.startswith(what)


@pytest.mark.parametrize("name", ["a\u00a0b.png", "a\u3000b.png", "a\x1cb.png"])
def test_a_name_with_a_space_python_splits_at_and_colmap_does_not_is_read_whole(tmp_path, name):
    """pycolmap reads such a name whole; the check refused it as a name with a space, which COLMAP cuts."""
    files = model(tmp_path, POSES.replace("a.png", name))
    assert colmap.text_model_errors(files) == (None, None)
    assert {image.name for image in pycolmap.Reconstruction(str(tmp_path)).images.values()} == {name, "b.png"}


@pytest.mark.parametrize("end", ["\n", ""])
def test_an_images_txt_whose_last_pose_has_no_points_line_is_refused_not_read_without_that_image(tmp_path, end):
    """As `"\\n".join(lines)` writes a last empty points line: pycolmap left the last image out, without a word."""
    files = model(tmp_path, POSES.removesuffix("\n\n") + end)
    assert len(pycolmap.Reconstruction(str(tmp_path)).images) == 1
    error, _ = colmap.text_model_errors(files)
    assert error is not None and error.what.startswith("images.txt ends with an image's pose without the line of its "
                                                       "2D points after it, so COLMAP would leave that image out")


@pytest.mark.parametrize(("points", "reason"), [
    ("10 20 9223372036854775808", "POINT3D_ID 9223372036854775808"),  # past 64 bits: pycolmap refused, naming no line
    ("10 20 99999999999999999999", "POINT3D_ID 99999999999999999999"),  # the fast path's 20 digits took it
    ("10 20 7.0 30 40 -1", "POINT3D_ID 7.0"),  # read as 7, then .0 30 40 as the next point
    ("10 20 1e3", "POINT3D_ID 1e3"),  # read as 1
])
def test_a_2d_points_point3d_id_the_reader_cannot_hold_is_named(tmp_path, monkeypatch, points, reason):
    """COLMAP reads a 2D point's POINT3D_ID as a signed 64-bit integer; both paths passed these."""
    files = model(tmp_path, POSES.replace("10 20 -1", points))
    what = (f"cannot parse images.txt line 2 ({reason} is not a whole number from -9223372036854775808 to "
            "9223372036854775807 (-1 for none))")
    assert colmap.text_model_errors(files)[0].what == what
    slow_only(monkeypatch)
    assert colmap.text_model_errors(files)[0].what == what


def test_a_2d_points_point3d_id_of_64_bits_is_read(tmp_path):
    files = model(tmp_path, POSES.replace("10 20 -1", "10 20 9223372036854775807 1 2 +7"))
    assert colmap.text_model_errors(files) == (None, None)
    assert pycolmap.Reconstruction(str(tmp_path)).images[1].num_points2D() == 2
