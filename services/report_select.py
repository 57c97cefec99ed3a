"""Which trial runs one report pools: a sweep's invocations, and the warnings when a table would pool runs that
are not seeds of one setting.

A sweep run twice (``flashnav sweep run`` again, say with another budget) leaves two invocations in MLflow,
each child run tagged ``invocation=<stamp>`` (services.sweep; a ``--resume`` keeps its stamp). A report of
``--sweep NAME`` pools them unless ``--invocation latest|STAMP`` keeps one; it then counts seed 0 twice, and
says so. An Optuna search's trials are different settings, which a threshold table pools as if they were seeds.
"""

from __future__ import annotations

import pandas as pd

LATEST = "latest"


def select_invocation(runs: pd.DataFrame, wanted: str | None) -> pd.DataFrame:
    """The rows of ``runs`` (normalised trial runs) from one invocation per sweep: ``latest`` (the newest stamp
    of each sweep) or the stamp given; None = all. ValueError, listing the stamps there are, when nothing is left."""
    if wanted is None:
        return runs
    stamps = runs["invocation"] if "invocation" in runs else pd.Series(pd.NA, index=runs.index)
    if wanted == LATEST:
        newest = stamps.groupby(runs["sweep"].fillna("")).transform("max")
        kept = runs[stamps.notna() & (stamps == newest)]
    else:
        kept = runs[stamps == wanted]
    if kept.empty:
        there = sorted(str(s) for s in stamps.dropna().unique())
        raise ValueError(f"--invocation {wanted}: no trial run from it; invocations there: "
                         f"{', '.join(there) or 'none (runs logged before invocations were tagged)'}")
    kept = kept.copy()
    kept.attrs = {**runs.attrs, "n_trials": int(len(kept)), "n_other_invocations": int(len(runs) - len(kept))}
    return kept


def pooling_warnings(runs: pd.DataFrame) -> list[str]:
    """One line per thing a threshold table of ``runs`` pools that is not n seeds of one setting."""
    warnings = []
    if "invocation" in runs:
        for sweep, group in runs.groupby(runs["sweep"].fillna("")):
            counts = group["invocation"].dropna().value_counts().sort_index()
            if len(counts) > 1:
                listed = ", ".join(f"{stamp}: {n} trial{'s' * (n > 1)}" for stamp, n in counts.items())
                warnings.append(f"sweep {sweep or '(untagged)'}: trials of {len(counts)} invocations pooled "
                                f"({listed}); --invocation latest or --invocation STAMP keeps one")
    if "search_trial" in runs:
        searched = sorted(str(s) for s in runs.loc[runs["search_trial"].notna(), "sweep"].dropna().unique())
        for sweep in searched:
            warnings.append(f"sweep {sweep} is an Optuna search: its rows pool the trials' different settings as "
                            "if they were seeds (the study's best setting: best_<robot>_<algorithm>.yaml in its "
                            "outputs; run that as a seed sweep to tabulate it)")
    keys = ["robot", "algorithm", "device_name"]
    seeded = runs[runs["seed"].notna()] if "seed" in runs else runs.iloc[:0]
    for key, group in seeded.groupby(keys):
        repeated = group["seed"].value_counts()
        repeated = repeated[repeated > 1].sort_index()
        if len(repeated):
            seeds = ", ".join(f"seed {int(s)} x{n}" for s, n in repeated.items())
            warnings.append(f"{'/'.join(map(str, key[:2]))} on {key[2]}: {seeds} counted as separate seeds")
    return warnings
