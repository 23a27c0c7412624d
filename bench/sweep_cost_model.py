#!/usr/bin/env python3
"""The cost of a `qdo sweep` grid on N GPUs, projected from measured joint-step times.

The grid is the paper's comparison: level counts x modes (do, do-finetune, qdo, qdo+a) x decoders
x seeds, each design trained EPOCHS x STEPS_PER_EPOCH steps (the paper: 50 epochs over 167 ICVL
scenes x 10 crops at batch 4, 418 steps an epoch). Per seed and decoder the runs are the ones
`qdo sweep` trains: one DO run at full precision; a qdo and a qdo+a run per level count; for a
network decoder a do-finetune run per level count that starts from the DO run (the Wiener
decoder's do-finetune is its closed-form refit: no training). Evaluations are left out (seconds
against hours).

The schedule is the one `mpirun qdo sweep` (or a job array in plan order) gives: cells in plan
order, each rank takes the next cell whose runs are not being trained by another rank, so a
do-finetune waits for its DO run. The makespan on N ranks is simulated with that rule; the
efficiency is (total run time / N) / makespan.

Usage: bench/sweep_cost_model.py STEP_TIMES.csv [--levels 2,4,8,16,32] [--seeds 3] [--epochs 50]
           [--steps-per-epoch 418] [--finetune-epochs 10] [--gpus 1,2,4,8,16,32,64]
STEP_TIMES.csv: bench/step_times.sh's output (case,preset,decoder,...,median_step_s,...); the
cases paper-resunet and paper-wiener give the two decoders' step times. Prints markdown tables.
"""
import argparse
import csv
import heapq


def runs_of_grid(levels, seeds, decoders, steps, finetune_steps):
    """The cells in plan order, each with the runs (name, seconds) it trains, shared DO runs first."""
    cells = []
    for seed in range(seeds):
        for dec, step_s in decoders:
            do = (f"do_{dec}_s{seed}", steps * step_s)
            cells.append([do])  # full
            for L in levels:
                cells.append([do])  # do at L: the DO run quantized
                if dec == "wiener":
                    cells.append([do])  # do-finetune = the closed-form refit
                else:
                    cells.append([do, (f"do-finetune_L{L}_{dec}_s{seed}", finetune_steps * step_s)])
                cells.append([(f"qdo_L{L}_{dec}_s{seed}", steps * step_s)])
                cells.append([(f"qdo+a_L{L}_{dec}_s{seed}", steps * step_s)])
    return cells


def makespan(cells, ranks):
    """Dispatch in plan order to the first free rank; a cell whose run another rank trains waits."""
    done = {}        # run -> time it finished
    running = {}     # run -> time it will finish (being trained)
    free = [(0.0, r) for r in range(ranks)]
    heapq.heapify(free)
    pending = list(range(len(cells)))
    end = 0.0
    while pending:
        t, r = heapq.heappop(free)
        # Runs whose training ended by t are finished.
        for run, f in list(running.items()):
            if f <= t:
                done[run] = f
                del running[run]
        pick = None
        for i in pending:
            if all(run in done or run not in running for run, _ in cells[i]):
                pick = i
                break
        if pick is None:  # every pending cell waits for a run in training: wait for the next to end
            heapq.heappush(free, (min(running.values()), r))
            continue
        pending.remove(pick)
        now = t
        for run, seconds in cells[pick]:
            if run in done:
                continue
            now += seconds
            running[run] = now
        heapq.heappush(free, (now, r))
        end = max(end, now)
    return end


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("step_times")
    ap.add_argument("--levels", default="2,4,8,16,32")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--epochs", type=int, default=50)
    ap.add_argument("--steps-per-epoch", type=int, default=418)
    ap.add_argument("--finetune-epochs", type=int, default=10)
    ap.add_argument("--gpus", default="1,2,4,8,16,32,64")
    a = ap.parse_args()
    step = {row["case"]: float(row["median_step_s"]) for row in csv.DictReader(open(a.step_times))}
    decoders = [("resunet-paper", step["paper-resunet"]), ("wiener", step["paper-wiener"])]
    levels = [int(x) for x in a.levels.split(",")]
    steps = a.epochs * a.steps_per_epoch
    cells = runs_of_grid(levels, a.seeds, decoders, steps, a.finetune_epochs * a.steps_per_epoch)
    runs = {}
    for c in cells:
        for run, s in c:
            runs[run] = s
    total = sum(runs.values())
    print(f"grid: {len(levels)} level counts x (do, do-finetune, qdo, qdo+a) x {len(decoders)} decoders x {a.seeds} seeds: "
          f"{len(cells)} cells, {len(runs)} training runs of {steps} steps (do-finetune {a.finetune_epochs * a.steps_per_epoch});"
          f" step times {', '.join(f'{d} {s:.4f} s' for d, s in decoders)}")
    print(f"total training time: {total / 3600:.1f} GPU-hours\n")
    print("| GPUs | makespan [h] | efficiency |\n|---:|---:|---:|")
    for n in (int(x) for x in a.gpus.split(",")):
        m = makespan(cells, n)
        print(f"| {n} | {m / 3600:.1f} | {total / n / m:.2f} |")


if __name__ == "__main__":
    main()
