"""bench.frame_starts: its arguments (the probe itself runs whole fits: a benchmark)."""

import pytest

from bench import frame_starts


@pytest.mark.parametrize("bad", ["12", "a-b", "3-4-5"])
def test_a_malformed_probe_range_is_one_clear_error(bad, capsys):
    with pytest.raises(SystemExit) as e:
        frame_starts.main(["dance_ortho3", "--probe", bad])
    assert e.value.code == 2
    assert f"--probe: expected A-B, got {bad!r}" in capsys.readouterr().err


def test_an_unknown_setting_is_one_clear_error(capsys):
    with pytest.raises(SystemExit) as e:
        frame_starts.main(["dance_ortho3", "--setting", "no_such_field=1"])
    assert e.value.code == 2
    assert "NAME a SequenceSettings field" in capsys.readouterr().err
