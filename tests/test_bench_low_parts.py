"""bench/low_parts.py: the fingers' lowest contacts and the section across a part."""


import numpy as np
import pytest
import trimesh

from bench import low_parts  # noqa: E402

from seggrasp.grasp.antipodal import AntipodalConfig  # noqa: E402
from seggrasp.hands import ROBOTIQ_2F85  # noqa: E402


def test_the_lowest_contacts_follow_the_sampler_settings():
    ordinary, pinch, band_top = low_parts.lowest_contacts(AntipodalConfig(), ROBOTIQ_2F85)
    # fingertips 3.5 mm up, 20 mm past the pad centres, contact at most 12 mm towards them
    assert ordinary == pytest.approx(0.0115)
    assert pinch == pytest.approx(0.0015 + 0.020 - 0.0165)
    # a pinch's fingertips 1.5 mm up, the pads on the part's side over the 0.5 mm band above them
    assert band_top == pytest.approx(0.0015 + 0.0005)
    narrower = AntipodalConfig(pinch_min_band=0.003)
    assert low_parts.lowest_contacts(narrower, ROBOTIQ_2F85)[2] == pytest.approx(0.0045)
    deeper = AntipodalConfig(table_clearance=0.002)
    assert low_parts.lowest_contacts(deeper, ROBOTIQ_2F85)[0] == pytest.approx(0.010)


def test_the_section_cuts_across_the_part_and_marks_its_segments():
    # a 100 x 40 x 2 mm plate (the part), long along x, lying 8 mm up on a 20 x 20 x 10 mm block under its centre
    plate = trimesh.creation.box((0.100, 0.040, 0.002))
    plate.apply_translation((0.0, 0.0, 0.009))
    block = trimesh.creation.box((0.020, 0.020, 0.010))
    block.apply_translation((-0.005, 0.0, 0.005))
    mesh = trimesh.util.concatenate([plate, block])
    part_faces = np.arange(len(plate.faces))
    segments, on_part = low_parts.part_section(mesh, part_faces)
    part = segments[on_part].reshape(-1, 2)
    assert part[:, 1].max() == pytest.approx(0.010)
    assert part[:, 1].min() == pytest.approx(0.008)
    # the cut is across the plate's long axis: it spans the 40 mm width, not the 100 mm length
    assert part[:, 0].max() - part[:, 0].min() == pytest.approx(0.040)
    assert not on_part.all()  # the block's faces under the plate's centre are cut too, in grey
    assert segments[~on_part].reshape(-1, 2)[:, 1].min() == pytest.approx(0.0)


@pytest.mark.slow
def test_the_picture_of_a_twin_part_is_written_and_a_wrong_part_is_refused(tmp_path, capsys):
    assert low_parts.main(["--parts", "knife_chef:blade", "--out", str(tmp_path)]) == 0
    picture = tmp_path / "knife_chef-blade-section.png"
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("| knife_chef | blade"))
    part_top = float(row.split("|")[3])
    assert 5.0 < part_top < 20.0
    with pytest.raises(SystemExit) as exit_info:
        low_parts.main(["--parts", "knife_chef:lid", "--out", str(tmp_path)])
    assert exit_info.value.code == 2
    assert "knife_chef has no part 'lid'" in capsys.readouterr().err
