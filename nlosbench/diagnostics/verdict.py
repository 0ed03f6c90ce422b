"""A verdict per parameter from recorded gradient metrics, and the backend choice for `grad="auto"`.

Rules (on the summary rows of the `gradients` study; FD with common random numbers is the control):
- an AD configuration is *biased* when its total derivative disagrees with the reference (the CI of
  the difference excludes 0): more spp does not fix it;
- it has *artifacts* at the highest spp when it has clearly more outlier pixels per image than FD at
  the same spp (more than EXCESS_PIXELS and more than EXCESS_FACTOR × FD's), or when its outliers do
  not fade with spp while FD's do (the paper's observation, 4096 → 16384 spp);
- otherwise it is *clean*.
A parameter is "AD clean" when an applicable AD integrator is clean; "AD artifact-prone" when some
are unbiased but none clean (use FD or a remedy: whichever reaches the target error at least cost);
"AD biased" when every AD integrator is biased; "undetermined" without AD rows, or when AD looks
clean on fewer than MIN_SEEDS seeds.
"""
from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..forward.bindings import GEOMETRY_KINDS
from ..forward.gradients import GradientSettings
from ..forward.model import ForwardModel
from ..io import write_text
from .images import backend, label, param_kind
from .metrics import spp_trend

EXCESS_PIXELS = 1.0
EXCESS_FACTOR = 1.5
#: fewer seeds give confidence intervals too wide to call AD clean (a t interval with 1 dof is ±12.7 SE)
MIN_SEEDS = 4
STATUS_TEXT = {"ad-clean": "AD clean",
               "ad-artifact-prone": "AD artifact-prone: use FD or median-of-K",
               "ad-biased": "AD biased: use FD",
               "undetermined": "undetermined (AD not measured, or too few seeds): use FD"}
#: the more general AD integrator handles what the less general ones do
_GENERALITY = ("prb", "direct_projective", "prb_projective")


@dataclass
class Verdict:
    """status: ad-clean | ad-artifact-prone | ad-biased | undetermined; text: for people;
    backend: spec of the recommended gradient backend (see images.backend); cheapest: label of the
    measured configuration that reaches the target error at least cost; reasons: the evidence.

    Examples
    --------
    >>> v = nb.diagnostics.Verdict("x", "ad-biased", "AD biased: use FD", {"method": "fd", "step": 0.01})
    >>> v.settings().method, v.settings().step
    ('fd', 0.01)
    """

    param: str
    status: str
    text: str
    backend: dict
    cheapest: str = ""
    reasons: list[str] = field(default_factory=list)

    def settings(self) -> GradientSettings:
        return backend(self.backend)


def _f(row: dict, key: str, default=float("nan")) -> float:
    v = row.get(key, "")
    return default if v in ("", None) else float(v)


def _is_true(v) -> bool:
    return v is True or str(v).lower() == "true"


def classify(row: dict, control: dict | None, low: dict | None, control_low: dict | None) -> tuple[str, str]:
    """('clean' | 'artifacts' | 'biased', reason) for one AD summary row at the top spp, given the FD
    control at that spp and (optionally) both at the lowest spp for the trend."""
    if not _is_true(row.get("agrees")):
        return "biased", (f"total derivative {_f(row, 'total'):.4g} vs reference {_f(row, 'ref_total'):.4g} "
                          f"(95% CI of the difference [{_f(row, 'ci_low'):.3g}, {_f(row, 'ci_high'):.3g}])")
    ad, fd = _f(row, "outlier_pixels_per_image"), _f(control, "outlier_pixels_per_image", 0.0) if control else 0.0
    if ad > EXCESS_PIXELS and ad > EXCESS_FACTOR * fd:
        return "artifacts", f"{ad:.3g} outlier pixels per image vs {fd:.3g} for FD at {row['spp']} spp"
    if low is not None and control_low is not None and ad > EXCESS_PIXELS:
        t_ad = spp_trend(_f(low, "outlier_pixels_per_image"), ad)
        t_fd = spp_trend(_f(control_low, "outlier_pixels_per_image"), fd)
        if t_ad in ("grow", "steady") and t_fd in ("fade", "none"):
            return "artifacts", f"outliers {t_ad} from {low['spp']} to {row['spp']} spp while FD's {t_fd}"
    return "clean", f"{ad:.3g} outlier pixels per image (FD: {fd:.3g}), total derivative agrees"


def judge(rows: list[dict], param: str) -> Verdict:
    """The verdict for `param` from summary rows (dicts with param, method, remedy, spp, spec, label,
    crn, applicable, outlier_pixels_per_image, agrees, total, ref_total, ci_low, ci_high,
    cost_to_target).

    Examples
    --------
    The committed Cornell-box study's summary rows give the verdicts it saved:

    >>> import csv
    >>> with open("results/cornell_gradients/00-gradients/summary.csv", newline="") as f:
    ...     rows = list(csv.DictReader(f))
    >>> [nb.diagnostics.judge(rows, p).status for p in ("red_x", "red_radius", "red_color")]
    ['ad-artifact-prone', 'ad-biased', 'ad-clean']
    """
    mine = [r for r in rows if r["param"] == param]
    if not mine:
        raise ValueError(f"no gradient metrics recorded for parameter {param!r}")
    fd = {int(r["spp"]): r for r in mine if r["method"] == "fd" and _is_true(r.get("crn")) and not r.get("remedy")}
    fd_spec = json.loads(fd[max(fd)]["spec"]) if fd else {"method": "fd"}
    plain = [r for r in mine if r["method"] == "ad" and not r.get("remedy") and not r.get("applicable")]
    reachable = [r for r in mine if np.isfinite(_f(r, "cost_to_target", np.inf))]
    cheapest = min(reachable, key=lambda r: _f(r, "cost_to_target")) if reachable else None
    cheapest_label = cheapest["label"] if cheapest else ""
    if not plain:
        return Verdict(param, "undetermined", STATUS_TEXT["undetermined"], fd_spec, cheapest_label,
                       ["no applicable AD integrator was measured"])
    top, low = max(int(r["spp"]) for r in plain), min(int(r["spp"]) for r in plain)
    found = {}
    for r in (r for r in plain if int(r["spp"]) == top):
        lo = next((x for x in plain if x["label"] == r["label"] and int(x["spp"]) == low), None) if low < top else None
        found[r["label"]] = (r, *classify(r, fd.get(top), lo, fd.get(low) if lo else None))
    reasons = [f"{lab}: {cls} — {why}" for lab, (_, cls, why) in found.items()]
    clean = [r for r, cls, _ in found.values() if cls == "clean"]
    if clean and all(_f(r, "seeds", MIN_SEEDS) < MIN_SEEDS for r in clean):
        return Verdict(param, "undetermined", STATUS_TEXT["undetermined"], fd_spec, cheapest_label,
                       reasons + [f"AD looks clean but with fewer than {MIN_SEEDS} seeds the test has little power"])
    if clean:
        # the clean integrator that reaches the target error soonest at any measured spp
        best = min(clean, key=lambda r: min(_f(x, "cost_to_target", np.inf) for x in plain if x["label"] == r["label"]))
        return Verdict(param, "ad-clean", STATUS_TEXT["ad-clean"], json.loads(best["spec"]), cheapest_label, reasons)
    status = "ad-artifact-prone" if any(cls == "artifacts" for _, cls, _ in found.values()) else "ad-biased"
    return Verdict(param, status, STATUS_TEXT[status], fd_spec, cheapest_label, reasons)


def save_verdicts(path: str | Path, verdicts: dict[str, Verdict]) -> Path:
    """Write `verdicts` (parameter → Verdict) as JSON to `path`, as a `gradients` study saves its verdicts.json;
    returns the path.

    Examples
    --------
    >>> import tempfile
    >>> v = nb.diagnostics.load_verdicts("results/cornell_gradients/00-gradients")
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     again = nb.diagnostics.load_verdicts(nb.diagnostics.save_verdicts(f"{tmp}/verdicts.json", v))
    >>> again == v
    True
    """
    return write_text(path, json.dumps({k: asdict(v) for k, v in verdicts.items()}, indent=2))


def load_verdicts(path: str | Path) -> dict[str, Verdict]:
    """Verdicts saved by a `gradients` study (its `verdicts.json`, or the study folder).

    Examples
    --------
    >>> v = nb.diagnostics.load_verdicts("results/cornell_gradients/00-gradients")
    >>> sorted(v), v["red_color"].text
    (['red_color', 'red_radius', 'red_x'], 'AD clean')
    """
    path = Path(path)
    if path.is_dir():
        path = path / "verdicts.json"
    if not path.is_file():
        raise FileNotFoundError(f"no gradient verdicts at {path} (run a `gradients` study first)")
    return {k: Verdict(**v) for k, v in json.loads(path.read_text()).items()}


def prior_settings(model: ForwardModel, index: int) -> GradientSettings:
    """The backend without measurements (the paper's finding): exact models and colour parameters
    use AD (`prb`), geometry and unknown parameters use FD."""
    if model.exact:
        return GradientSettings("ad")
    kind = param_kind(model, index)
    if kind is not None and kind not in GEOMETRY_KINDS:
        return GradientSettings("ad", ad={"type": "prb"})
    return GradientSettings("fd")


def _as_verdicts(verdicts) -> dict[str, Verdict]:
    if verdicts is None:
        return {}
    if isinstance(verdicts, Mapping):
        bad = [k for k, v in verdicts.items() if not isinstance(v, Verdict)]
        if bad:
            raise ValueError(f"verdicts for {bad} are not Verdict objects (load them with load_verdicts)")
        return dict(verdicts)
    return load_verdicts(verdicts)


def choose_backend(model: ForwardModel, verdicts: Mapping[str, Verdict] | str | Path | None = None,
                   base: GradientSettings | None = None) -> GradientSettings:
    """Concrete GradientSettings for all parameters of `model` (what `grad="auto"` becomes).

    Per parameter: AD when its verdict says "AD clean" (by `verdicts`, a mapping or a saved
    verdicts.json / study folder), or, without a verdict, by `prior_settings` (colour → AD, geometry
    → FD). All AD parameters share one AD pass with the most general of their integrators. The result
    is "ad", "fd", or "mixed" (AD for some parameters, FD for the rest); `.chosen` says per parameter
    what was picked and why. base: the "auto" settings being resolved: its FD step / rounds / crn and
    spp are kept, its `ad` options override the chosen integrator's. Without `base`, FD uses the
    settings of the first verdict that recommends FD (else the defaults).

    Examples
    --------
    An exact toy without a verdict takes AD for every parameter:

    >>> s = nb.diagnostics.choose_backend(nb.scenes.get("blob2d"))
    >>> s.method, s.chosen
    ('ad', 'x → ad:auto (prior: exact model); y → ad:auto (prior: exact model)')
    """
    found = _as_verdicts(verdicts)
    names = list(model.params.names)
    if found and not set(found) & set(names):  # verdicts for other parameters (e.g. of a restriction) are ignored
        raise ValueError(f"the verdicts (for {sorted(found)}) name no parameter of {model.name!r} "
                         f"(parameters: {names})")
    choices, why = [], []
    for j, n in enumerate(names):
        if n in found:
            choices.append(found[n].settings())
            why.append(f"verdict: {found[n].text}")
        else:
            choices.append(prior_settings(model, j))
            kind = param_kind(model, j)
            why.append("prior: exact model" if model.exact else f"prior: {kind or 'unknown'} parameter")
    ad_idx = tuple(j for j, c in enumerate(choices) if c.method == "ad")
    ad_choices = [choices[j] for j in ad_idx]
    ad = max(ad_choices, key=lambda c: _GENERALITY.index(c.ad.get("type", "prb"))).ad if ad_choices else {}
    if base is None:
        fd = next((c for c in choices if c.method == "fd"), GradientSettings("fd"))
        step, rounds, crn, spp, user_ad = fd.step, fd.rounds, fd.crn, None, {}
    else:
        step, rounds, crn, spp, user_ad = base.step, base.rounds, base.crn, base.spp, base.ad
    method = "ad" if len(ad_idx) == len(names) else "fd" if not ad_idx else "mixed"
    ad = {**ad, **user_ad} if ad_idx else {}
    fd_label, ad_label = label(GradientSettings("fd", step, rounds, crn)), label(GradientSettings("ad", ad=ad))
    chosen = "; ".join(f"{n} → {ad_label if j in ad_idx else fd_label} ({why[j]})" for j, n in enumerate(names))
    return GradientSettings(
        method,
        step=step,
        rounds=rounds,
        crn=crn,
        spp=spp,
        ad=ad,
        ad_params=ad_idx if method == "mixed" else (),
        chosen=chosen,
    )
