"""masks.tracked: the track-id files, tracks.json, id images of a tracker's output, and the
classical tracker's geometry-free parts."""

import json

import numpy as np
import pytest
from PIL import Image

from masks.tracked import (
    TrackFileError,
    agreement,
    ids_path,
    load_ids,
    load_tracks_info,
    match_segments,
    overlap_iou,
    read_id_image,
    remap_ids,
    save_ids,
    save_tracks_info,
    segments_from_masks,
)


def test_ids_path_shares_the_mask_files_stem(tmp_path):
    import masks

    for name in ("00012", "cam01/00003"):
        a, b = masks.mask_path(tmp_path, name), ids_path(tmp_path, name)
        assert a.parent == b.parent and a.name.removesuffix(".masks") == b.name.removesuffix(".ids.png")
    assert ids_path(tmp_path, "cam01/00003").name == "cam01__00003.ids.png"


def test_ids_round_trip_through_a_16_bit_png(tmp_path):
    ids = np.zeros((5, 7), np.int64)
    ids[1:3, 2:6] = 3
    ids[4, 6] = 65535
    path = save_ids(tmp_path / "v.ids.png", ids)
    got = load_ids(path)
    assert got.dtype == np.int32 and got.shape == (5, 7)
    np.testing.assert_array_equal(got, ids)
    assert [p.name for p in tmp_path.iterdir()] == ["v.ids.png"]  # no temp file left behind


@pytest.mark.parametrize("bad", [np.full((2, 2), -1), np.full((2, 2), 70000), np.zeros((2, 2, 3), int),
                                 np.zeros((2, 2), float)])
def test_save_ids_refuses_what_a_16_bit_map_cannot_hold(tmp_path, bad):
    with pytest.raises(TrackFileError, match="v.ids.png"):
        save_ids(tmp_path / "v.ids.png", bad)
    assert not (tmp_path / "v.ids.png").exists()


def test_load_ids_errors_name_the_file_on_one_line(tmp_path):
    import cv2

    cases = {"missing.ids.png": None, "empty.ids.png": b"", "corrupt.ids.png": b"\x89PNG\r\n\x1a\nnot really"}
    for name, data in cases.items():
        if data is not None:
            (tmp_path / name).write_bytes(data)
    cv2.imwrite(str(tmp_path / "eight.ids.png"), np.zeros((3, 3), np.uint8))
    cv2.imwrite(str(tmp_path / "rgb.ids.png"), np.zeros((3, 3, 3), np.uint16))
    for name, what in (("missing.ids.png", "no such"), ("empty.ids.png", "not a readable PNG"),
                       ("corrupt.ids.png", "not a readable PNG"), ("eight.ids.png", "16-bit single-channel"),
                       ("rgb.ids.png", "3 channel")):
        with pytest.raises(TrackFileError) as exc:
            load_ids(tmp_path / name)
        msg = str(exc.value)
        assert str(tmp_path / name) in msg and what in msg and "\n" not in msg


def test_tracks_info_round_trip_and_errors(tmp_path):
    save_tracks_info(tmp_path, {"source": "files", "n_tracks": 4, "tracks_dir": "x"})
    assert load_tracks_info(tmp_path) == {"source": "files", "n_tracks": 4, "tracks_dir": "x"}
    with pytest.raises(TrackFileError, match="source"):
        save_tracks_info(tmp_path, {"source": "deva", "n_tracks": 1})
    empty = tmp_path / "none"
    empty.mkdir()
    with pytest.raises(TrackFileError, match="no tracks.json"):
        load_tracks_info(empty)
    (empty / "tracks.json").write_text("{not json")
    with pytest.raises(TrackFileError, match="cannot read tracks.json"):
        load_tracks_info(empty)
    (empty / "tracks.json").write_text(json.dumps({"source": "classical"}))
    with pytest.raises(TrackFileError, match="n_tracks"):
        load_tracks_info(empty)


def test_remap_keeps_ids_consistent_across_maps():
    a = np.array([[0, 500], [7, 7]])
    b = np.array([[500, 500], [0, 90000]])
    (ra, rb), mapping = remap_ids([a, b])
    assert mapping == {7: 1, 500: 2, 90000: 3}
    np.testing.assert_array_equal(ra, [[0, 2], [1, 1]])
    np.testing.assert_array_equal(rb, [[2, 2], [0, 3]])


def test_id_images_in_each_of_devas_encodings(tmp_path):
    ids = np.array([[0, 1, 1], [2, 2, 0]], np.uint8)
    Image.fromarray(ids, "L").save(tmp_path / "short.png")  # --use_short_id, Gaussian Grouping's input
    pal = Image.fromarray(ids, "P")
    pal.putpalette([0, 0, 0, 255, 0, 0, 0, 255, 0] + [0] * (256 * 3 - 9))  # colours must not matter
    pal.save(tmp_path / "palette.png")
    long_ids = np.array([[0, 300], [70000, 0]], np.int64)  # DEVA's long ids, RGB = id in base 256
    rgb = np.stack([long_ids % 256, long_ids // 256 % 256, long_ids // 65536], -1).astype(np.uint8)
    Image.fromarray(rgb, "RGB").save(tmp_path / "long.png")
    np.testing.assert_array_equal(read_id_image(tmp_path / "short.png"), ids)
    np.testing.assert_array_equal(read_id_image(tmp_path / "palette.png"), ids)
    np.testing.assert_array_equal(read_id_image(tmp_path / "long.png"), long_ids)
    Image.fromarray(np.zeros((2, 2), np.float32), "F").save(tmp_path / "float.tiff")
    with pytest.raises(TrackFileError, match="float.tiff.*mode F"):
        read_id_image(tmp_path / "float.tiff")
    with pytest.raises(TrackFileError, match="nothing.png: no such file"):
        read_id_image(tmp_path / "nothing.png")


def test_segments_let_the_largest_mask_take_each_pixel():
    big = np.zeros((10, 11), bool)
    big[:, :6] = True  # 60 px
    part = np.zeros_like(big)
    part[:5, :3] = True  # inside big: eaten whole, no segment of its own
    side = np.zeros_like(big)
    side[:, 5:10] = True  # 50 px, 10 of them under big: keeps 40/50 = 0.8 -> a segment
    crumb = np.zeros_like(big)
    crumb[0, 10] = True
    seg = segments_from_masks(np.stack([part, side, big, crumb]), min_kept=0.8, min_area=2)
    assert seg.max() == 2
    assert (seg[big] == 1).all()  # largest first
    assert (seg[:, 6:10] == 2).all() and seg[0, 10] == 0  # the crumb is below min_area: left at 0
    assert (segments_from_masks(np.stack([big, side]), min_kept=0.9) > 0).sum() == 60  # side keeps 0.8 < 0.9


def test_matching_is_one_to_one_above_the_threshold():
    seg = np.array([[1, 1, 2, 2], [1, 1, 2, 2]])
    warped = np.array([[2, 2, 1, -1], [2, 2, 0, -1]])  # -1: unknown pixels say nothing
    iou = overlap_iou(seg, warped, 2, 2)
    np.testing.assert_allclose(iou, [[0.0, 1.0], [0.5, 0.0]])
    assert match_segments(iou, 0.5) == {0: 1}  # 0.5 is not above one half
    assert match_segments(iou, 0.4) == {0: 1, 1: 0}
    assert match_segments(np.zeros((0, 3)), 0.5) == {}


def test_agreement_counts_masks_that_follow_their_tracks_object():
    truth = [np.array([[1, 1, 2, 2]]), np.array([[1, 1, 2, 2]])]
    good = [np.array([[1, 1, 2, 2]]), np.array([[1, 1, 2, 2]])]
    assert agreement(good, truth)["masks"] == 1.0 and agreement(good, truth)["tracks_per_object"] == 1.0
    swapped = [np.array([[1, 1, 2, 2]]), np.array([[1, 1, 1, 1]])]  # track 1 covers object 2 too
    a = agreement(swapped, truth)
    assert a["n_masks"] == 3 and a["masks"] == 1.0 and a["pixels"] == 6 / 8
    jumped = [np.array([[1, 1, 2, 2]]), np.array([[2, 2, 1, 1]])]  # ids exchanged in view 2
    assert agreement(jumped, truth)["masks"] == 0.5
    # object 1 in two tracks (3 pixels and 1), object 2 in one
    split = [np.array([[1, 1, 2, 2]]), np.array([[1, 3, 2, 2]])]
    a = agreement(split, truth)
    assert a["tracks_per_object"] == 1.5 and a["main_track_pixels"] == (3 / 4 + 1.0) / 2
    assert agreement(good, truth)["main_track_pixels"] == 1.0


def test_each_track_is_the_object_most_of_its_pixels_show_over_the_sequence():
    from masks.tracked import track_objects

    truth = [np.array([[1, 1, 2, 2]]), np.array([[1, 1, 2, 2]]), np.array([[1, 1, 2, 2]])]
    # track 1 takes object 2 in one view (3 pixels of object 1 against 2); track 3 only object 2;
    # "no track" (0) has no object
    ids = [np.array([[1, 1, 0, 3]]), np.array([[1, 0, 1, 1]]), np.array([[1, 1, 3, 3]])]
    assert track_objects(ids, truth) == {1: 1, 3: 2}
    assert track_objects([np.array([[1, 1]])], [np.array([[2, 1]])]) == {1: 1}  # a tie: the lower id


def test_a_segment_inside_one_track_is_a_part_of_it():
    from masks.tracked import overlap_counts, part_of

    seg = np.array([[1, 1, 2, 2, 3, 3]])
    warped = np.array([[1, 1, 1, 1, 1, 2]])  # segments 1 and 2 lie in track 1; 3 straddles 1 and 2
    inter, known, _ = overlap_counts(seg, warped, 3, 2)
    area = np.array([2, 2, 2])
    assert part_of(inter, known, area, 0.8) == {0: 0, 1: 0}
    unknown = np.array([[-1, -1, 1, 1, -1, -1]])  # segment 1 unseen before: no evidence, no part
    inter, known, _ = overlap_counts(seg, unknown, 3, 2)
    assert part_of(inter, known, area, 0.8) == {1: 0}


def test_a_lost_track_is_carried_where_no_mask_or_a_merged_one_holds_it():
    from masks.tracked import carry_lost

    # one row: a floor segment (1) that merged the blob (warped track 7 at columns 2-3), a missed
    # mask (0) where track 8 warps, and a segment (2) that is mostly track 9
    seg = np.array([[1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 2, 2, 2]])
    ids = np.array([[4, 4, 4, 4, 4, 4, 4, 4, 0, 0, 5, 5, 5]])  # the segments' tracks
    warped = np.array([[-1, 4, 7, 7, 4, 4, 4, 4, 8, 8, 9, 9, 5]])
    out, carried = carry_lost(ids, seg, warped, [7, 8, 9], min_area=2)
    assert carried == [7, 8]
    assert out.tolist() == [[4, 4, 7, 7, 4, 4, 4, 4, 8, 8, 5, 5, 5]]  # track 9 is 2/3 of segment 2: its own
    assert ids.tolist()[0][2] == 4  # the input is not changed
    out, carried = carry_lost(ids, seg, warped, [7, 8], min_area=3)  # too few pixels: not carried
    assert carried == [] and np.array_equal(out, ids)
    spread = np.array([[-1, 4, 7, 7, 4, 4, 4, 4, 9, 9, 9, 9, 5]])  # 9 also on missed pixels: not carried at all
    out, carried = carry_lost(ids, seg, spread, [7, 9], min_area=2)
    assert carried == [7] and (out != 9).all()
    out, carried = carry_lost(ids, seg, warped, [], min_area=1)
    assert carried == [] and np.array_equal(out, ids)
