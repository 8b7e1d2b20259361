"""H-step RMS of the default mixture against the best tuned peer (issue: time, lead, intervals).

Run: python -m benchmarks.lead_vs_peers [--datasets hawkeye_ball cycling skillcorner paper]
     [--horizons 2 5 10] [--json out.json]

For each recording (and the paper's simulated stereo target, seed 0) and each horizon H,
:func:`kalmix.experiments.evaluate.evaluate_table` with its peers, exactly what
``kalmix evaluate -H H`` prints: the default mixture's H-step RMS (lead weights), every
peer's H-step RMS (each tuned on the first 20 % of every track, one-step RMS), the best
of them and the ratio; target <= 0.97.
"""

from __future__ import annotations

from kalmix.experiments import evaluate as ev

from .lead_and_intervals import arguments, over_datasets

#: Rows of ``evaluate`` that are not peers: the mixture itself, its parts and the references.
NOT_PEERS = ("mixture", "AKF mixture", "best expert", "no prediction", "single AKF")


def horizon_peers(overall: dict) -> tuple[dict, str]:
    """Every tuned peer's H-step RMS in an evaluation's ``overall`` (those with an H-step forecast), and the best."""
    peers = {row: scores["horizon"]["rms"] for row, scores in overall.items()
             if not row.startswith(NOT_PEERS) and (scores.get("horizon") or {}).get("rms") is not None}
    return peers, min(peers, key=peers.get)


def _against_peers(name, table, h):
    overall = ev.evaluate_table(table, horizon=h, log=lambda *_: None).overall
    peers, best = horizon_peers(overall)
    mixture = overall["mixture"]["horizon"]["rms"]
    entry = {"mixture_rms": mixture, "best_peer": best, "best_peer_rms": peers[best],
             "ratio": mixture / peers[best], "peers": peers}
    return entry, f"mixture {mixture:.5g}, best peer {best} {peers[best]:.5g}, ratio {entry['ratio']:.3f}"


def main(argv=None):
    return over_datasets(arguments(__doc__, argv), _against_peers)


if __name__ == "__main__":
    main()
