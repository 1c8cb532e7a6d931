"""Loading the WPI-format CSV, and every bad input raising its named error."""

from pathlib import Path

import numpy as np
import pytest

from calibration.datasets import (ColumnCountError, ConstantSignalError, EmptyDataError, JointData,
                                  NonFiniteError, NonMonotonicTimeError, load_csv, processed,
                                  split_blocks)

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "wpi-psm" / "one_results.csv"
if not REAL.exists():
    REAL = Path("/work/shared/data/wpi-psm/one_results.csv")


def write(tmp_path, rows, name="data.csv"):
    p = tmp_path / name
    p.write_text("\n".join(",".join(str(v) for v in r) for r in rows) + "\n")
    return p


def good_rows(n=50, joints=2, seed=0):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 3 * joints)).round(6).tolist()


@pytest.mark.skipif(not REAL.exists(), reason="shared data not present")
def test_real_file_loads():
    d = load_csv(REAL)
    assert d.q.shape == (5999, 7) and d.dq.shape == (5999, 7) and d.tau.shape == (5999, 7)
    assert d.rate == 200.0 and d.t[-1] == pytest.approx(5998 / 200)
    d3 = load_csv(REAL, joints=3)
    assert d3.q.shape == (5999, 3)
    np.testing.assert_array_equal(d3.q, d.q[:, :3])
    np.testing.assert_array_equal(d3.tau, d.tau[:, :3])  # columns 15-17, not 8-10
    # The insertion joint stays within its stroke (m): q3 is the third position column.
    assert 0.0 < d3.q[:, 2].min() and d3.q[:, 2].max() < 0.25
    p = processed(d3)
    assert p.ddq.shape == p.q.shape and p.n_samples < 5999


def test_group_order(tmp_path):
    rows = [[1, 2, 10, 20, 100, 200], [3, 4, 30, 40, 300, 400]]
    d = load_csv(write(tmp_path, rows), rate=100, joints=1)
    np.testing.assert_array_equal(d.q[:, 0], [1, 3])
    np.testing.assert_array_equal(d.dq[:, 0], [10, 30])
    np.testing.assert_array_equal(d.tau[:, 0], [100, 300])
    np.testing.assert_array_equal(d.t, [0.0, 0.01])


def test_column_count_not_multiple_of_three(tmp_path):
    rows = [r[:-1] for r in good_rows()]
    with pytest.raises(ColumnCountError, match=r"data\.csv, line 1: 5 columns is not a multiple of 3"):
        load_csv(write(tmp_path, rows))


def test_fewer_joints_than_asked(tmp_path):
    with pytest.raises(ColumnCountError, match="3 joints asked but the file has 6 columns"):
        load_csv(write(tmp_path, good_rows()), joints=3)


def test_truncated_last_line(tmp_path):
    rows = good_rows()
    rows[-1] = rows[-1][:4]
    with pytest.raises(ColumnCountError, match=r"line 50: 4 columns where line 1 has 6 \(truncated row\)"):
        load_csv(write(tmp_path, rows))


def test_nan_names_line_and_column(tmp_path):
    rows = good_rows()
    rows[4][3] = "nan"  # line 5, column 4 = dq2
    rows[9][0] = "inf"
    with pytest.raises(NonFiniteError, match=r"line 5, column 4 \(dq2\)"):
        load_csv(write(tmp_path, rows))


def test_nan_in_unused_joint_is_ignored(tmp_path):
    rows = good_rows()
    rows[4][3] = "nan"  # dq2: not used when only joint 1 is loaded
    assert load_csv(write(tmp_path, rows), joints=1).n_samples == 50


def test_not_a_number(tmp_path):
    rows = good_rows()
    rows[7][5] = "abc"
    with pytest.raises(NonFiniteError, match=r"line 8, column 6 \(tau2\): 'abc' is not a number"):
        load_csv(write(tmp_path, rows))


def test_empty_file(tmp_path):
    p = tmp_path / "empty.csv"
    p.write_text("\n\n")
    with pytest.raises(EmptyDataError, match="empty.csv: file is empty"):
        load_csv(p)


def test_constant_joint(tmp_path):
    rows = good_rows()
    for r in rows:
        r[1] = 0.25  # q2 never moves
    with pytest.raises(ConstantSignalError, match="q2 is constant.*joint 2"):
        load_csv(write(tmp_path, rows))


def test_non_monotonic_time():
    n = 100
    q = np.random.default_rng(0).normal(size=(n, 2))
    t = np.arange(n) * 0.005
    t[40] = t[38]
    with pytest.raises(NonMonotonicTimeError, match=r"run\.mcap: time does not increase at sample 40"):
        JointData.from_arrays(q, q, q, t=t, source="run.mcap")
    ok = JointData.from_arrays(q, q, q, t=np.arange(n) * 0.005)
    assert ok.rate == pytest.approx(200.0)


def test_from_arrays_errors():
    q = np.random.default_rng(0).normal(size=(10, 2))
    with pytest.raises(ColumnCountError, match="same shape"):
        JointData.from_arrays(q, q[:, :1], q, rate=100)
    bad = q.copy()
    bad[3, 1] = np.nan
    with pytest.raises(NonFiniteError, match="tau2 at sample 3"):
        JointData.from_arrays(q, q, bad, rate=100)


def test_split_blocks_are_contiguous(tmp_path):
    d = load_csv(write(tmp_path, good_rows(n=100)))
    train, held = split_blocks(d, 0.25)
    assert (train.n_samples, held.n_samples) == (75, 25)
    np.testing.assert_array_equal(np.concatenate([train.q, held.q]), d.q)
    assert "held-out rows 76-100" in held.source
    train, held = split_blocks(d, 0.2, heldout="start")
    np.testing.assert_array_equal(held.q, d.q[:20])
    with pytest.raises(ValueError, match="heldout_fraction"):
        split_blocks(d, 1.5)
