"""Research (issue 53, scale.md "Round 4"; run with PYTHONPATH at the checkout). From a full search's trials (search_trials.py --no-floor --out), where the pruning-floor rule
would stop the ladder, how many trials it saves and whether the chosen trial is the same."""
import json, math, sys
from lghcc.encoder.gaussians import gaussian_rd as rd
for path in sys.argv[1:]:
    d = json.load(open(path))
    start, target = d["ladder_start"]
    tr = [rd.Trial(None, m, b, 0.0) for m, b in d["trials"]]
    shares = [x[0] for x in d["shares"]]
    base_dc = [x[1] for x in d["shares"]]
    # the ladder's trials by share, in order (a share's first trial may be the search's best, not re-run)
    groups, i = [], start
    while i < len(tr):
        j = i
        while j < len(tr) and shares[j] == shares[i]:
            j += 1
        groups.append((shares[i], list(range(i, j))))
        i = j
    stop = len(tr)
    for share, idx in groups:
        f0 = base_dc[idx[0]]
        tried = {base_dc[k] / f0: tr[k] for k in idx}
        if rd.at_pruning_floor(tried, target):
            stop = idx[-1] + 1
            print(f"  stops after share {share} (trials {idx[0]}-{idx[-1]}: " +
                  ", ".join(f"{-10*math.log10(tr[k].mse):.2f} dB" for k in idx) + ")")
            break
    full = rd.fewest_bits_meeting(tr, target)
    cut = rd.fewest_bits_meeting(tr[:stop], target)
    cpu = sum(c for _, c in d["times"]); cut_cpu = sum(c for _, c in d["times"][:stop])
    print(f"{path}: {len(tr)} trials -> {stop}; trial CPU {cpu:.0f} -> {cut_cpu:.0f} s; chosen trial "
          f"{tr.index(full)} -> {tr.index(cut)} ({'the same' if full is cut else 'DIFFERENT'}): "
          f"{-10*math.log10(full.mse):.2f} dB {full.bits/8:,.0f} B")
