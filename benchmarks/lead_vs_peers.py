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

import time

from kalmix.experiments import evaluate as ev

from .lead_and_intervals import arguments, save, table_of

#: Rows of ``evaluate`` that are not peers: the mixture itself, its parts and the references.
NOT_PEERS = ("mixture", "AKF mixture", "best expert", "no prediction", "single AKF")


def main(argv=None):
    args = arguments(__doc__, argv)
    report = {}
    for name in args.datasets:
        table = table_of(name)
        report[name] = {}
        for h in args.horizons:
            start = time.perf_counter()
            overall = ev.evaluate_table(table, horizon=h, log=lambda *_: None).overall
            peers = {row: scores["horizon"]["rms"] for row, scores in overall.items()
                     if not row.startswith(NOT_PEERS) and (scores.get("horizon") or {}).get("rms") is not None}
            best = min(peers, key=peers.get)
            mixture = overall["mixture"]["horizon"]["rms"]
            entry = {"mixture_rms": mixture, "best_peer": best, "best_peer_rms": peers[best],
                     "ratio": mixture / peers[best], "peers": peers, "seconds": time.perf_counter() - start}
            report[name][f"H={h}"] = entry
            print(f"{name} H={h}: mixture {mixture:.5g}, best peer {best} {peers[best]:.5g}, "
                  f"ratio {entry['ratio']:.3f} ({entry['seconds']:.0f}s)", flush=True)
    save(report, args.json)
    return report


if __name__ == "__main__":
    main()
