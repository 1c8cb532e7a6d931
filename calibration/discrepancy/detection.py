"""Where the held-out residual is structured and which variable explains it."""

from __future__ import annotations

import numpy as np

from calibration.discrepancy.residual_tests import binned_r2, heldout_r2, ljung_box

#: Travel scales (fractions of a joint's stroke) of the detection library's after-reversal
#: features.
TRAVEL_SCALES = (0.005, 0.02)


def detection_variable(w, name: str) -> np.ndarray:
    """The detection variable `name` (q1, dq2, travel3, ...) of ``w``: the `Discrepancy`."""
    p = w.p
    j = int(name[-1]) - 1
    if name.startswith("travel"):
        return np.abs(p.qf[:, j] - _last_reversal_position(p.qf[:, j], p.dqf[:, j], p.kept_starts()))
    return {"q": p.qf, "dq": p.dqf, "ddq": p.ddqf, "u": w.tau_model}[name[:-1]][:, j]


def _last_reversal_position(q: np.ndarray, dq: np.ndarray, starts=()) -> np.ndarray:
    """Position at the last velocity reversal before each sample; a recording that begins at
    an index of ``starts`` begins as if it reversed there (what came before is unknown)."""
    s = np.sign(dq)
    out = np.empty_like(q)
    last = q[0]
    starts = set(starts)
    for k in range(len(q)):
        if k in starts or (k and s[k] != 0 and s[k] != s[k - 1]):
            last = q[k]
        out[k] = last
    return out


class Detection:
    """The workflow's detection, a `Discrepancy` mixin: the library, the tests per joint, the attribution."""

    def _library(self) -> np.ndarray:
        """(m, k) generic features for the predictability test, kept domain."""
        p = self.p
        raw = []
        for i in range(3):
            v = p.dq[:, i]
            s = np.tanh(0.5 * self.slope * v)
            vs = np.std(v) * 0.05
            raw += [p.q[:, i], p.q[:, i] ** 2, s, v, v * np.abs(v), s * np.exp(-(v / vs) ** 2), s * p.q[:, i]]
            # The regime just after a reversal (pre-sliding, play): the direction fading with
            # the travel since the last reversal, over two scales of the joint's stroke.
            travel = np.abs(p.qf_all[:, i] - _last_reversal_position(p.qf_all[:, i], p.dqf_all[:, i],
                                                                      p.raw_starts()))
            stroke = np.subtract(*np.quantile(p.qf_all[:, i], [0.99, 0.01]))
            raw += [np.sign(p.dqf_all[:, i]) * np.exp(-travel / (f * stroke)) for f in TRAVEL_SCALES]
        F = p.filt(np.column_stack(raw))
        extra = [p.ddqf]
        u = self.tau_model_raw
        lag = int(round(0.02 * p.rate))
        u_lag = p.filt_rows(p.piecewise(lambda v: np.vstack([v[:1].repeat(lag, 0), v[:-lag]]) - v, u))
        return np.column_stack([F] + extra + [self.tau_model, u_lag])

    def detect(self) -> list[dict]:
        """Per joint: Ljung-Box Q and library R^2 of the held-out residual vs thresholds."""
        r = self.residual()
        p = self.p
        spacing = max(1, int(round(p.rate / (2.0 * p.cutoff))))
        F = self._library()
        out = []
        for j in range(3):
            tr, ho = self.mov_tr[j], self.mov_ho[j]
            q_lb = ljung_box(r[ho, j][::spacing])
            r2 = heldout_r2(F[tr], r[tr, j], F[ho], r[ho, j])
            structured = bool(q_lb > self.th["ljung_box"][j] or r2 > self.th["library_r2"][j])
            out.append({"joint": j + 1, "ljung_box": q_lb, "ljung_box_threshold": self.th["ljung_box"][j],
                        "library_r2": r2, "library_r2_threshold": self.th["library_r2"][j],
                        "structured": structured})
        return out

    def attribute(self, joint: int) -> dict:
        """The variable and regime that best explain joint's residual (binned held-out R^2)."""
        p = self.p
        r = self.residual()[:, joint - 1]
        j = joint - 1
        spacing = max(1, int(round(p.rate / (2.0 * p.cutoff))))
        travel = np.abs(p.qf[:, j] - _last_reversal_position(p.qf[:, j], p.dqf[:, j], p.kept_starts()))
        t = np.arange(self.m) / p.rate
        variables = {f"q{j + 1}": p.qf[:, j], f"dq{j + 1}": p.dqf[:, j], f"ddq{j + 1}": p.ddqf[:, j],
                     f"u{j + 1}": self.tau_model[:, j], f"travel since reversal {j + 1}": travel}
        for i in range(3):
            if i != j:
                variables[f"dq{i + 1}"] = p.dqf[:, i]
                variables[f"q{i + 1}"] = p.qf[:, i]
        scores = {}
        tr, ho = self.mov_tr[j], self.mov_ho[j]
        for name, x in variables.items():
            r2, rng, mean = binned_r2(x[tr], r[tr], x[ho], r[ho])
            scores[name] = {"heldout_r2": r2, "regime": list(rng), "regime_mean": mean}
        best = max(scores, key=lambda k: scores[k]["heldout_r2"])
        xc = {}
        for name in (f"dq{j + 1}", f"ddq{j + 1}"):
            x = variables[name][ho][::spacing]
            rr = r[ho][::spacing]
            xc[name] = float(np.max(np.abs(np.correlate((rr - rr.mean()) / (rr.std() * len(rr)),
                                                        (x - x.mean()) / (x.std() + 1e-300), "full"))))
        del t
        return {"variable": best, "regime": scores[best]["regime"], "by_variable": scores,
                "max_cross_correlation": xc}
