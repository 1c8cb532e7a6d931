"""Motive CSV reader/writer: the exact layout, units, quaternion order, occlusions, errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.mocap.motive_csv import MotiveCsvError, read_motive_csv, write_motive_csv
from drivers.common.quaternion import (matrix_to_quat_xyzw, quat_xyzw_to_matrix, reorder_quaternion,
                                wxyz_to_xyzw, xyzw_to_wxyz)

# A Motive 2.x export as Motive writes it (hand-typed from the documented layout):
# rigid body "Tool" with its mean marker error, one rigid body marker, one labelled
# marker, millimetres, frame 1 has the body and the marker occluded.
MOTIVE_MM = (
    "Format Version,1.23,Take Name,Take 2018-06-01 02.03.04 PM,Take Notes,,Capture Frame Rate,120.000000,"
    "Export Frame Rate,120.000000,Capture Start Time,2018-06-01 02.03.04.567 PM,Capture Start Frame,0,"
    "Total Frames in Take,3,Total Exported Frames,3,Rotation Type,Quaternion,Length Units,Millimeters,"
    "Coordinate Space,Global\r\n"
    "\r\n"
    ",Type,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,"
    "Rigid Body Marker,Rigid Body Marker,Rigid Body Marker,Rigid Body Marker,Marker,Marker,Marker\r\n"
    ",Name,Tool,Tool,Tool,Tool,Tool,Tool,Tool,Tool,Tool:Marker1,Tool:Marker1,Tool:Marker1,Tool:Marker1,"
    "Tool:Marker1,Tool:Marker1,Tool:Marker1\r\n"
    ",ID,1,1,1,1,1,1,1,1,1:1,1:1,1:1,1:1,1:1,1:1,1:1\r\n"
    ",,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Mean Marker Error,Position,Position,"
    "Position,Marker Quality,Position,Position,Position\r\n"
    "Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,,X,Y,Z,,X,Y,Z\r\n"
    "0,0.000000,0.000000,0.000000,0.382683,0.923880,-1.490000,-516.110000,2.190000,0.120000,"
    "10.000000,-500.000000,3.000000,1.000000,10.100000,-500.100000,3.050000\r\n"
    "1,0.008333,,,,,,,,,,,,,,,\r\n"
    "2,0.016667,0.000000,0.000000,0.000000,1.000000,1.000000,2.000000,3.000000,0.150000,"
    "11.000000,-499.000000,3.500000,0.900000,11.100000,-499.050000,3.450000\r\n"
)


def write(tmp_path, text, name="take.csv"):
    f = tmp_path / name
    f.write_bytes(text.encode())
    return f


def test_reads_motive_export_in_millimetres_as_metres(tmp_path):
    take = read_motive_csv(write(tmp_path, MOTIVE_MM))
    assert take.length_unit == "Millimeters" and take.frame_rate == 120.0
    np.testing.assert_allclose(take.time, [0.0, 0.008333, 0.016667])
    tool = take.body("Tool")
    assert tool.id == "1"
    np.testing.assert_allclose(tool.position[0], [-1.49e-3, -0.51611, 2.19e-3])
    np.testing.assert_allclose(tool.mean_marker_error[[0, 2]], [0.12e-3, 0.15e-3])
    # 45 deg about z, given x,y,z,w in the file
    np.testing.assert_allclose(tool.rotation()[0], Rotation.from_euler("z", 45, degrees=True).as_matrix(),
                               atol=1e-6)
    m = take.marker("Tool:Marker1")
    np.testing.assert_allclose(m.position[2], [0.0111, -0.49905, 0.00345])
    assert take.rigid_body_markers["Tool:Marker1"].quality[0] == 1.0


def test_occluded_samples_are_nan_with_mask_never_zero(tmp_path):
    take = read_motive_csv(write(tmp_path, MOTIVE_MM))
    tool = take.body("Tool")
    assert tool.valid.tolist() == [True, False, True]
    assert np.all(np.isnan(tool.position[1])) and np.all(np.isnan(tool.quaternion_xyzw[1]))
    assert take.marker("Tool:Marker1").valid.tolist() == [True, False, True]
    frames = take.tracker_frames()
    assert frames[1].bodies["Tool"] is None and frames[1].markers["Tool:Marker1"] is None
    assert frames[2].bodies["Tool"].position[0] == pytest.approx(1e-3)


@pytest.mark.parametrize("units", ["m", "mm"])
@pytest.mark.parametrize("order", ["xyzw", "wxyz"])
def test_writer_round_trip_units_and_quaternion_order(tmp_path, units, order):
    rng = np.random.default_rng(3)
    n = 50
    t = np.arange(n) / 120.0
    q = Rotation.random(n, random_state=4).as_quat()  # x, y, z, w
    p = rng.uniform(-1, 1, (n, 3))
    p[7] = np.nan
    q[7] = np.nan
    mk = rng.uniform(-1, 1, (n, 3))
    mk[[3, 4]] = np.nan
    f = write_motive_csv(tmp_path / "w.csv", t, {"PSM1_tool": (p, q)}, markers={"W1": mk},
                         units=units, quat_order=order)
    lines = f.read_text().splitlines()
    assert lines[0].startswith("Format Version,1.23,") and ",Rotation Type,Quaternion," in lines[0]
    assert lines[1] == ""
    assert lines[2].startswith(",Type,Rigid Body") and lines[5].startswith(",,Rotation")
    assert lines[6].startswith("Frame,Time (Seconds)," + ",".join(order.upper()) + ",X,Y,Z,")
    take = read_motive_csv(f)
    b = take.body("PSM1_tool")
    assert b.valid.sum() == n - 1 and not b.valid[7]
    np.testing.assert_allclose(b.position[b.valid], p[b.valid], atol=1e-6)
    # sign of q is free; compare rotations
    np.testing.assert_allclose(b.rotation()[b.valid], quat_xyzw_to_matrix(q[b.valid]), atol=1e-5)
    assert take.marker("W1").valid.tolist() == [k not in (3, 4) for k in range(n)]


def test_forced_quaternion_order_for_mislabelled_files(tmp_path):
    """A tool that writes w first under X,Y,Z,W labels: the caller says so explicitly."""
    text = MOTIVE_MM.replace("0.000000,0.000000,0.382683,0.923880", "0.923880,0.000000,0.000000,0.382683")
    f = write(tmp_path, text)
    wrong = read_motive_csv(f).body("Tool").rotation()[0]
    right = read_motive_csv(f, quat_order="wxyz").body("Tool").rotation()[0]
    np.testing.assert_allclose(right, Rotation.from_euler("z", 45, degrees=True).as_matrix(), atol=1e-6)
    assert not np.allclose(wrong, right, atol=1e-2)


def test_quaternion_order_functions():
    q = np.array([[0.1, 0.2, 0.3, 0.9]])
    assert xyzw_to_wxyz(q).tolist() == [[0.9, 0.1, 0.2, 0.3]]
    assert wxyz_to_xyzw(xyzw_to_wxyz(q)).tolist() == q.tolist()
    assert reorder_quaternion(q, "xyzw", "xyzw").tolist() == q.tolist()
    R = Rotation.random(5, random_state=1).as_matrix()
    np.testing.assert_allclose(quat_xyzw_to_matrix(matrix_to_quat_xyzw(R)), R, atol=1e-12)
    assert np.all(matrix_to_quat_xyzw(R)[:, 3] >= 0)
    with pytest.raises(ValueError, match="unknown quaternion order"):
        reorder_quaternion(q, "xyzw", "zyxw")


def test_not_a_motive_export(tmp_path):
    f = write(tmp_path, "time,x,y,z\n0,1,2,3\n")
    with pytest.raises(MotiveCsvError, match=r"take.csv:1: not a Motive CSV export.*'time'"):
        read_motive_csv(f)


def test_missing_body_lists_names_present(tmp_path):
    take = read_motive_csv(write(tmp_path, MOTIVE_MM))
    with pytest.raises(MotiveCsvError, match=r"no rigid body named 'PSM2'.*present: 'Tool'"):
        take.body("PSM2")


def test_euler_rotation_type_is_refused(tmp_path):
    text = MOTIVE_MM.replace("Rotation Type,Quaternion", "Rotation Type,XYZ")
    with pytest.raises(MotiveCsvError, match=r":1: Rotation Type is 'XYZ' \(Euler angles\), not Quaternion"):
        read_motive_csv(write(tmp_path, text))


def test_truncated_row_names_line(tmp_path):
    text = MOTIVE_MM.rstrip("\r\n")
    text = text[: text.rfind(",0.900000")] + "\r\n"  # export cut off mid-row
    with pytest.raises(MotiveCsvError, match=r"take.csv:10: truncated row: 13 cells, the header has 17"):
        read_motive_csv(write(tmp_path, text))


def test_non_numeric_cell_names_line_and_column(tmp_path):
    text = MOTIVE_MM.replace("-516.110000", "-516.11O000")
    with pytest.raises(MotiveCsvError, match=r"take.csv:8: non-numeric cell '-516.11O000' in column 8 "
                                             r"\(Tool Position Y\)"):
        read_motive_csv(write(tmp_path, text))


def test_rotation_columns_that_are_not_a_quaternion(tmp_path):
    text = MOTIVE_MM.replace("0.000000,0.000000,0.382683,0.923880", "1.000000,2.000000,0.382683,0.923880")
    with pytest.raises(MotiveCsvError, match=r":8: Rigid Body 'Tool': rotation is not a unit quaternion"):
        read_motive_csv(write(tmp_path, text))
