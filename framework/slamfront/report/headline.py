"""The few sentences a run ends with: on the console, and first in the report.

Each sentence appears when the run has the metrics it needs (a loop detector, a back end,
a localizer); every number a run computes is in ``metrics.json``.
"""

from __future__ import annotations

from typing import Any


def _number(metrics: dict[str, Any], *keys: str) -> bool:
    return all(isinstance(metrics.get(k), int | float) and not isinstance(metrics.get(k), bool) for k in keys)


def headline(metrics: dict[str, Any]) -> list[str]:
    """The sentences, most telling first."""
    m = metrics
    lines = []
    if _number(m, "ate_rmse_before_m", "ate_rmse_after_m"):
        lines.append(f"ATE before -> after optimisation: {m['ate_rmse_before_m']:.3g} m -> {m['ate_rmse_after_m']:.3g} m")
    if _number(m, "drift_before_m", "drift_after_m", "drift_before_percent", "drift_after_percent"):
        lines.append(f"drift at the last frame: {m['drift_before_m']:.3g} m -> {m['drift_after_m']:.3g} m "
                     f"({m['drift_before_percent']:.2g} % -> {m['drift_after_percent']:.2g} % of the distance)")
    if _number(m, "recall_at_100p", "auc_pr"):
        line = f"loop closure: recall {m['recall_at_100p']:.3f} at 100 % precision, AUC-PR {m['auc_pr']:.3f}"
        if _number(m, "precision_at_operating_point", "recall_at_operating_point"):
            line += "; at the detector's operating point"
            if _number(m, "accept_threshold"):
                how = "calibrated" if m.get("accept_auto") else "given"
                score = "supported confidence" if m.get("accept_on_supported_confidence") else "confidence"
                t = m["accept_threshold"]  # just above 0: no wrong answer had any (the supported confidence's case)
                either = (f" or supported confidence >= {m['accept_threshold_supported']:.3g}"
                          if _number(m, "accept_threshold_supported") else "")
                score = "confidence" if either else score
                line += f" ({score} {f'>= {t:.3g}' if t >= 1e-12 or t <= 0 else '> 0'}{either}, {how})"
            if _number(m, "n_accepted"):
                line += f" it accepts {m['n_accepted']} answers"
            if m.get("n_accepted") == 0:
                line += " (no loop closure reaches its threshold)"  # a precision of nothing is no number
            else:
                line += (f"{':' if _number(m, 'n_accepted') else ''} precision {m['precision_at_operating_point']:.3f}, "
                         f"recall {m['recall_at_operating_point']:.3f}")
        lines.append(line)
    if _number(m, "n_loop_constraints_added", "n_loop_constraints_added_false"):
        skipped = m.get("n_loop_constraints_skipped")
        rejected = f"; {skipped} rejected" if isinstance(skipped, int) else ""
        lines.append(f"the back end verified {m['n_loop_constraints_added']} loop closures "
                     f"({m['n_loop_constraints_added_false']} of them wrong){rejected}")
    if _number(m, "ate_rmse_m"):
        rpe = f", RPE {m['rpe_rmse_m']:.3g} m" if _number(m, "rpe_rmse_m") else ""
        lines.append(f"trajectory: ATE {m['ate_rmse_m']:.3g} m{rpe}")
    if _number(m, "n_frames", "frames_per_second"):
        lines.append(f"{m['n_frames']} frames at {m['frames_per_second']:.3g} frames/s")
    return lines
