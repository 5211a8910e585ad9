"""CPU seconds of a fit's final local solve (``FINAL_SOLVE``): its compile and its run, for
checkouts of bubblefit taken in turns, on one validation case's fit level.

    PYTHONPATH=. python experiments/rim_solve_cost.py capture CASE OUT.pkl [--code DIR]
    PYTHONPATH=. python experiments/rim_solve_cost.py measure OUT.pkl NAME=DIR[@SAMPLES,BAND,RULE] ...
        [--rounds 1] [--move-nm 15] [--json RECORD.json]

``capture`` fits CASE (drainage, as ``experiments/validation/validate.py`` runs it) with the
code in DIR and keeps the final solve's level, table, settings, map and solution.
``measure`` starts that solve from the solution with the drainage's top and bottom moved
by ``--move-nm``, once per checkout and round, each in a fresh process with bubblefit
imported from DIR: the compile CPU (trace, lower, XLA) and HLO instruction count of the
solve's program, and the CPU of 3 runs of it; ``@SAMPLES,BAND,RULE`` sets the rim's rays,
band and quadrature (``SolveSettings.rim_samples``, ``rim_band``, ``rim_rule``) where the
checkout has them.

The capture is a pickle of bubblefit's own objects (the level, table, map), made by
``capture`` for ``measure`` on the same machine: it is written readable by its owner
alone, and ``measure`` reads only a file it finds so (a pickle runs code when loaded;
never give it a file from elsewhere).
"""
from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def capture(case: str, out: str) -> None:
    """Fit ``case`` with its drainage model and pickle the final solve's arguments."""
    import bubblefit.inverse.fit as F
    from bubblefit.cli import main

    data = os.path.join(HERE, "validation", "data")
    with open(os.path.join(data, case, "truth.json")) as fh:
        truth = json.load(fh)
    kept = []
    solve_local = F.solve_local

    def keep(*a, **k):
        sol = solve_local(*a, **k)
        if "max_steps" not in k and len(a) < 6:
            kept.append((a, k, sol.values))
        return sol

    F.solve_local = keep
    work = os.path.join(os.path.dirname(os.path.abspath(out)), "capture")
    os.makedirs(work, exist_ok=True)
    cdir = os.path.join(data, case)
    code = main(["fit", os.path.join(cdir, "photo.png"), "--envmap", os.path.join(data, truth["envmap"]),
                 "--background", os.path.join(cdir, "background.png"), "--thickness", "drainage", "--fov", "0",
                 "--json", os.path.join(work, "fit.json"), "-o", os.path.join(work, "fit")])
    if code != 0 or not kept:
        sys.exit(f"capture: the fit of {case} ended with code {code} and {len(kept)} final solves")
    a, k, values = kept[-1]
    lev, table, solver, _, env = a[:5]
    with open(os.open(out, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600), "wb") as fh:
        pickle.dump({"case": case, "lev": lev, "table": table, "solver": solver, "env": env,
                     "values": values, "settings": k.get("settings")}, fh)
    print(f"kept the final solve of {case}: {int(lev.mask.sum())} fitted blocks, free {table.free}")


def one(pkl: str, move_nm: float, rim: str | None) -> dict:
    """One process's compile and runs of the final solve (this process's bubblefit)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import bubblefit.inverse._programs as P

    st = os.stat(pkl)
    if st.st_uid != os.getuid() or st.st_mode & 0o077:
        sys.exit(f"measure: {pkl} is not a capture of this user's alone (owner only, mode 600); not loaded")
    with open(pkl, "rb") as fh:
        d = pickle.load(fh)
    lev, table, env = d["lev"], d["table"], d["env"]
    vals = dict(d["values"])
    for name in vals:
        if name in ("top_nm", "bottom_nm", "thickness_top_nm", "thickness_bottom_nm"):
            vals[name] = vals[name] + move_nm
    settings = P.FINAL_SOLVE
    row = {"code": P.__file__}
    if rim is not None:
        samples, band, rule = rim.split(",")
        settings = P.replace(settings, rim_samples=int(samples), rim_band=float(band), rim_rule=rule)
    if hasattr(P, "rim_blocks"):
        band = getattr(settings, "rim_band", P.RIM_BAND)
        row["rim"] = {"samples": settings.rim_samples, "band": band, "rule": getattr(settings, "rim_rule", "box"),
                      "blocks": int(P.rim_blocks(lev, band).sum()) if settings.rim_samples else 0}
    key, args, _ = P.solve_program(lev, table, d["solver"], vals, env, None, settings)
    solve = P.solver(*key)[0]
    z = jnp.asarray(table.unconstrained(vals), jnp.float32)
    c0, t0 = time.process_time(), time.perf_counter()
    compiled = solve.lower(z, args).compile()
    row["compile_cpu_s"] = round(time.process_time() - c0, 2)
    row["compile_wall_s"] = round(time.perf_counter() - t0, 2)
    text = compiled.as_text() or ""
    row["hlo_instructions"] = sum(1 for line in text.splitlines()
                                  if " = " in line and not line.lstrip().startswith(("HloModule", "//")))
    runs = []
    for _ in range(3):
        c0, t0 = time.process_time(), time.perf_counter()
        out = [np.asarray(x) for x in compiled(z, args)]
        runs.append((round(time.process_time() - c0, 2), round(time.perf_counter() - t0, 2)))
    zf = table.values(jnp.asarray(out[0]), args[0])
    row.update(run_cpu_s=[c for c, _ in runs], run_wall_s=[w for _, w in runs], steps=int(out[3]),
               rays=int(np.prod(np.asarray(args[-1][0]).shape)),
               reached={k: round(float(zf[k]), 3) for k in table.free}, load=round(os.getloadavg()[0], 1))
    return row


def measure(pkl: str, checkouts: list, rounds: int, move_nm: float, record: str | None) -> None:
    """Each checkout ``(name, folder, rim or None)``, in turns, ``rounds`` times."""
    rows = []
    for rnd in range(rounds):
        for name, path, rim in checkouts:
            cmd = [sys.executable, os.path.abspath(__file__), "one", pkl, "--move-nm", str(move_nm)]
            cmd += ["--rim", rim] if rim else []
            env = dict(os.environ, PYTHONPATH=os.path.abspath(path))
            p = subprocess.run(cmd, env=env, capture_output=True, text=True)
            if p.returncode != 0:
                sys.exit(f"{name}: {(p.stderr.strip().splitlines() or [''])[-1]}")
            row = dict(json.loads(p.stdout.strip().splitlines()[-1]), name=name, round=rnd)
            rows.append(row)
            print(json.dumps(row), flush=True)
            if record:
                with open(record, "w") as fh:
                    json.dump({"command": " ".join(sys.argv), "rows": rows}, fh, indent=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="what", required=True)
    c = sub.add_parser("capture")
    c.add_argument("case")
    c.add_argument("out")
    o = sub.add_parser("one")
    o.add_argument("pkl")
    o.add_argument("--move-nm", type=float, default=15.0)
    o.add_argument("--rim")
    m = sub.add_parser("measure")
    m.add_argument("pkl")
    m.add_argument("checkouts", nargs="+", help="NAME=DIR[@SAMPLES,BAND,RULE] (RULE: gauss, box)")
    m.add_argument("--rounds", type=int, default=1)
    m.add_argument("--move-nm", type=float, default=15.0)
    m.add_argument("--json")
    a = ap.parse_args()
    if a.what == "capture":
        if os.path.exists(a.out):
            sys.exit(f"capture: {a.out} exists; not overwritten")
        capture(a.case, a.out)
    elif a.what == "one":
        print(json.dumps(one(a.pkl, a.move_nm, a.rim)))
    else:
        jobs = []
        for x in a.checkouts:
            name, _, rest = x.partition("=")
            path, _, rim = rest.partition("@")
            if not name or not os.path.isdir(path) or (rim and len(rim.split(",")) != 3):
                sys.exit(f"measure: {x}: each checkout is NAME=DIR[@SAMPLES,BAND,RULE], DIR a folder")
            jobs.append((name, path, rim or None))
        if a.json and os.path.exists(a.json):
            sys.exit(f"measure: {a.json} exists; not overwritten")
        measure(a.pkl, jobs, a.rounds, a.move_nm, a.json)


if __name__ == "__main__":
    main()
