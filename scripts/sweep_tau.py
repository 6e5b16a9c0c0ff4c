"""How the promotion threshold tau trades acceptance speed against false acceptance.

For each tau: the share of steps with an estimate on streams of only wrong alignments (1-4 per
step, uniform over +-spread metres and all headings), and on streams with a correct alignment
(0.2 m / 2 deg noise, 0-4 wrong ones per step) the update at which the first estimate comes and
the share of steps with an estimate, for 20 % and 50 % empty steps. Means over seeds.

    python scripts/sweep_tau.py [--taus 12 8 4 0 -4] [--seeds 5]
"""

from __future__ import annotations

import argparse

import numpy as np
from tcaff_gtsam.eval.sim.streams import alignment_stream, wrong_alignments

from tcaff_gtsam import TCAFF, TCAFFParams
from tcaff_gtsam.params import constant_alignment_covariance

R = constant_alignment_covariance()
SPREADS = (15.0, 5.0, 2.0, 1.0)


def estimates(params: TCAFFParams, zs_per_step) -> list:
    filt = TCAFF(params)
    return [filt.update(zs, np.broadcast_to(R, (len(zs), 3, 3))) for zs in zs_per_step]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--taus", type=float, nargs="+", default=[12.0, 8.0, 4.0, 0.0, -4.0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--steps", type=int, default=600)
    args = parser.parse_args()
    head = " ".join(f"{f'wrong {s:g} m':>10}" for s in SPREADS)
    print(f"{'tau':>6} {head} {'first@20%':>10} {'avail@20%':>10} {'first@50%':>10} "
          f"{'avail@50%':>10}")
    for tau in args.taus:
        params = TCAFFParams(tau=tau)
        false_share = []
        for spread in SPREADS:
            shares = []
            for seed in range(args.seeds):
                rng = np.random.default_rng(seed)
                zs = [wrong_alignments(rng, int(rng.integers(1, 5)), spread)
                      for _ in range(args.steps)]
                shares.append(np.mean([e is not None for e in estimates(params, zs)]))
            false_share.append(np.mean(shares))
        cells = []
        for p_empty in (0.2, 0.5):
            firsts, avail = [], []
            for seed in range(args.seeds):
                stream = alignment_stream(np.random.default_rng(seed), 200, p_empty=p_empty)
                est = estimates(params, stream.zs)
                got = [i + 1 for i, e in enumerate(est) if e is not None]
                firsts.append(got[0] if got else np.nan)
                avail.append(len(got) / len(est))
            cells += [np.nanmean(firsts), np.mean(avail)]
        row = " ".join(f"{s:10.3f}" for s in false_share)
        print(f"{tau:6.1f} {row} {cells[0]:10.1f} {cells[1]:10.3f} {cells[2]:10.1f} "
              f"{cells[3]:10.3f}")


if __name__ == "__main__":
    main()
