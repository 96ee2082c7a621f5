"""``python -m tests.fuzz``: runs the fuzz cases and writes the summary table.

    PYTHONPATH=python python -m tests.fuzz --cases 2400 --seed 1 --out docs/fuzz-results.md
    PYTHONPATH=python python -m tests.fuzz --replay packet:17 --seed 1   # one case, kept on disk
    PYTHONPATH=python python -m tests.fuzz --pinned    # the hand-picked cases alone (pinned.py)

Exit status 0 when every case ended as "specific error" or "accepted", 1 otherwise.
"""

from __future__ import annotations

import argparse
import datetime
import json
import random
import re
import secrets
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import tests.fuzz  # noqa: F401 - sets the thread-pool variables before numpy is imported
from tests.fuzz import targets
from tests.fuzz.harness import Outcome, Verdict, run_case
from tests.fuzz.pinned import PINNED

#: Address space a case may take beyond the fork server's own (bytes): a frame of the
#: decoder's largest camera (2^25 pixels, about 1 GB of buffers) fits, 30 GB does not.
MEM_BUDGET = 2 << 30
#: What ``splitrender serve`` prints once it serves, and ``splitrender relay`` once it relays
#: (both until interrupted, by design; the relay for its ``--seconds`` where given).
_LISTENING = re.compile(r"^(listening on|relaying) ", re.MULTILINE)
#: The heading in tests/fuzz/targets.py's docstring under which the checks are listed.
_WHY = "Why accepting is right, per kind (the check each ``run`` makes):"
#: The CI profile: cases and seed (tests/test_fuzz.py); it also runs the hand-picked cases.
CI_CASES, CI_SEED = 250, 20261202
#: The kind of the hand-picked cases' results (their index: the position in ``PINNED``).
PINNED_KIND = "pinned"


@dataclass(frozen=True)
class Result:
    kind: str
    index: int
    mutation: str
    outcome: str
    detail: str


def plan(total: int, kinds: list[str]) -> dict[str, int]:
    """Cases per kind, in proportion to the kinds' weights (each at least one)."""
    weights = {k: targets.KINDS[k].weight for k in kinds}
    s = sum(weights.values())
    return {k: max(1, round(total * w / s)) for k, w in weights.items()}


def _work(run: Callable[[], None], cli: bool) -> Callable[[], Verdict]:
    def work() -> Verdict:
        if cli:
            try:
                run()
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
                return Verdict(Outcome.ACCEPTED, f"exit {code}")
            return Verdict(Outcome.ACCEPTED, "exit 0")
        run()
        return Verdict(Outcome.ACCEPTED, "")

    return work


def run_one(kind: str, index: int, seed: int, seeds: Path, work: Path) -> Result:
    if kind == PINNED_KIND:
        return run_pinned(index, seeds, work)
    k = targets.KINDS[kind]
    rng = random.Random(f"{seed}:{kind}:{index}")
    case_dir = work / f"{kind}-{index}"
    shutil.rmtree(case_dir, ignore_errors=True)
    case_dir.mkdir(parents=True)
    mutation, run, opts = k.make(rng, seeds, case_dir)
    verdict = _run_made(k, run, opts)
    return Result(kind, index, mutation, verdict.outcome.value, verdict.detail)


def run_pinned(index: int, seeds: Path, work: Path) -> Result:
    """Runs the hand-picked case ``PINNED[index]``: good only as a specific error whose text
    matches its ``expect``."""
    p = PINNED[index]
    case_dir = work / f"{PINNED_KIND}-{index}"
    shutil.rmtree(case_dir, ignore_errors=True)
    case_dir.mkdir(parents=True)
    what, run, opts = p.make(seeds, case_dir)
    v = _run_made(targets.KINDS[p.kind], run, opts)
    if v.outcome is Outcome.ACCEPTED:
        v = Verdict(Outcome.WRONG_ACCEPT, f"accepted; expected an error matching {p.expect!r}")
    elif v.outcome is Outcome.SPECIFIC and not re.search(p.expect, v.detail):
        v = Verdict(Outcome.UNEXPECTED, f"expected an error matching {p.expect!r}, got: "
                    f"{v.detail}")
    return Result(PINNED_KIND, index, f"{p.kind} {p.name}: {what}", v.outcome.value, v.detail)


def _run_made(k: targets.Kind, run: Callable[[], None], opts: dict[str, object]) -> Verdict:
    """Runs a case's ``run`` (with its ``opts``) in a forked child; its verdict."""
    cli = bool(opts.get("cli"))
    serve = bool(opts.get("serve"))

    def log_check(v: Verdict, output: str) -> Verdict:
        return targets.classify_cli(v, output) if cli else v

    fsize_limit = opts.get("fsize_limit")
    return run_case(
        _work(run, cli),
        time_limit=k.time_limit,
        mem_budget=MEM_BUDGET,
        fsize_limit=fsize_limit if isinstance(fsize_limit, int) else None,
        log_check=log_check,
        running=_LISTENING if serve else None,
        long_by_design=bool(opts.get("long")),
    )


def preload() -> None:
    """Imports everything the cases use once, here, so that no child pays for it (importing
    starts no thread; run_case checks)."""
    import av  # noqa: F401
    import OpenEXR  # noqa: F401
    import PIL.Image

    PIL.Image.init()  # the format plugins, which Image.open would otherwise load in each child

    import splitrender
    import splitrender.cli.dispatch
    import splitrender.codec.coder
    import splitrender.scene.dataset  # noqa: F401


def build_seeds(seeds: Path) -> None:
    """Generates the seeds afresh in ``seeds`` (in a child: the encoder starts threads)."""
    shutil.rmtree(seeds, ignore_errors=True)
    seeds.mkdir(parents=True)
    def work() -> Verdict:
        targets.build_seeds(seeds)
        return Verdict(Outcome.ACCEPTED, "")

    v = run_case(work, time_limit=600.0, mem_budget=MEM_BUDGET)
    if v.outcome != Outcome.ACCEPTED:
        raise RuntimeError(f"building the seeds failed: {v.outcome.value}: {v.detail}")


def run_all(
    cases: int, seed: int, kinds: list[str], work: Path, progress: bool = True,
    pinned: bool = False,
) -> tuple[list[Result], float]:
    """Runs ``cases`` cases (split over ``kinds``; none when 0) and, with ``pinned``, the
    hand-picked cases (pinned.py) after them; returns the results and the wall time."""
    start = time.monotonic()
    seeds = work / "seeds"
    build_seeds(seeds)
    results: list[Result] = []
    counts = plan(cases, kinds) if cases else {}
    if pinned:
        counts[PINNED_KIND] = len(PINNED)
    total = sum(counts.values())
    for kind, n in counts.items():
        for i in range(n):
            r = run_one(kind, i, seed, seeds, work / "cases")
            shutil.rmtree(work / "cases" / f"{kind}-{i}", ignore_errors=True)
            results.append(r)
            if progress and (len(results) % 100 == 0 or not Outcome(r.outcome).good):
                bad = "" if Outcome(r.outcome).good else f"  {r.kind}:{r.index} {r.outcome}: {r.detail[:120]}"
                print(f"[{len(results)}/{total} {time.monotonic() - start:.0f} s]{bad}", file=sys.stderr)
    return results, time.monotonic() - start


def table(results: list[Result]) -> str:
    outcomes = list(Outcome)
    kinds = list(dict.fromkeys(r.kind for r in results))
    head = "| kind | cases | " + " | ".join(o.value for o in outcomes) + " |"
    rule = "|---|---:|" + "---:|" * len(outcomes)
    rows = []
    for k in [*kinds, "all"]:
        rs = [r for r in results if k in ("all", r.kind)]
        cells = [str(sum(r.outcome == o.value for r in rs)) for o in outcomes]
        name = "**all**" if k == "all" else f"`{k}`"
        rows.append(f"| {name} | {len(rs)} | " + " | ".join(cells) + " |")
    return "\n".join([head, rule, *rows])


def report(results: list[Result], seed: int, command: str, seconds: float, examples: int = 5) -> str:
    bad = [r for r in results if not Outcome(r.outcome).good]
    why = (targets.__doc__ or "").split(_WHY, 1)[-1].strip()
    lines = [
        "# Fuzz results",
        "",
        "Structure-aware fuzzing of every input splitrender parses (issue 15; harness in",
        "`tests/fuzz/`, CI subset in `tests/test_fuzz.py`). Each case mutates a small valid input",
        "generated by the harness and runs the parser in a forked child under a memory limit",
        f"({MEM_BUDGET >> 30} GiB of address space beyond the fork server's) and a time limit.",
        "Only \"specific error\" (an exception of `splitrender.errors`' hierarchy; for the command",
        "line exit status 2 with exactly one `splitrender: error:` line) and \"accepted\" (with the",
        "check below) are good outcomes. \"wrongly accepted\": accepted, but the input had to be",
        "refused or what was read back is not well-formed.",
        "",
        f"- command: `{command}`",
        f"- seed: {seed}",
        f"- cases: {len(results)}",
        f"- wall time: {seconds:.0f} s ({datetime.date.today().isoformat()}, shared 2-core machine)",
        "",
        table(results),
        "",
        "## Why an accepted case is right",
        "",
        "What each kind's check verifies before an accepted case counts as accepted:",
        "",
        why,
        "",
        "## Hand-picked cases (CI profile)",
        "",
        pinned_list(),
        "",
        "## Cases with a bad outcome",
        "",
    ]
    if not bad:
        lines.append("None.")
    groups: dict[tuple[str, str], list[Result]] = {}
    for r in bad:
        groups.setdefault((r.kind, r.outcome), []).append(r)
    for (kind, outcome), rs in groups.items():
        lines.append(f"### `{kind}`: {outcome} ({len(rs)})")
        lines.append("")
        for r in rs[:examples]:
            mutation = r.mutation.replace("|", "\\|").replace("\n", " ")
            detail = r.detail.replace("|", "\\|").replace("\n", " ")
            lines.append(f"- `{kind}:{r.index}` {mutation}  \n  → {detail}")
        if len(rs) > examples:
            lines.append(f"- … and {len(rs) - examples} more")
        lines.append("")
    lines.append(f"Replay one case with `python -m tests.fuzz --seed {seed} --replay KIND:INDEX`.")
    return "\n".join(lines).rstrip() + "\n"


def pinned_list() -> str:
    """The hand-picked cases (pinned.py) as Markdown, for the report."""
    rows = [f"| `{PINNED_KIND}:{i}` | `{p.kind}` | {p.name} | {p.check} | "
            f"`{p.expect.replace('|', chr(92) + '|')}` |" for i, p in enumerate(PINNED)]
    return "\n".join([
        "The CI profile (`python -m tests.fuzz --ci`) runs these after its random draw, which",
        "need not reach a given check (`--pinned` runs them alone; tests/fuzz/pinned.py). Each",
        "must end as a specific error whose text matches the expression (`re.search`):",
        "accepted, it counts as \"wrongly accepted\"; refused by another error, as \"not the",
        "expected error\".",
        "",
        "| case | kind | name | the check it pins | the error must match |",
        "|---|---|---|---|---|",
        *rows,
    ])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tests.fuzz", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--cases", type=int, default=2400, help="number of cases (default: %(default)s)")
    p.add_argument("--seed", type=int, default=None, help="seed (default: a random one, printed)")
    p.add_argument("--ci", action="store_true",
                   help=f"the CI profile: {CI_CASES} cases, seed {CI_SEED} (unless given), "
                   f"then the {len(PINNED)} hand-picked cases")
    p.add_argument("--pinned", action="store_true",
                   help="run only the hand-picked cases (tests/fuzz/pinned.py)")
    p.add_argument("--kinds", default=",".join(targets.KINDS),
                   help="comma-separated kinds (default: all)")
    p.add_argument("--out", type=Path, default=None, help="write the Markdown summary here")
    p.add_argument("--json", type=Path, default=None, help="write every case's result here")
    p.add_argument("--work", type=Path, default=None,
                   help="working folder (default: a temporary one, removed)")
    p.add_argument("--replay", default=None, metavar="KIND:INDEX",
                   help="run one case, print it and keep its files under --work")
    args = p.parse_args(argv)
    cases = CI_CASES if args.ci and args.cases == 2400 else args.cases
    seed = args.seed if args.seed is not None else (CI_SEED if args.ci else secrets.randbelow(2**31))
    print(f"fuzz seed {seed}", file=sys.stderr)
    kinds = [k for k in args.kinds.split(",") if k]
    unknown = set(kinds) - set(targets.KINDS)
    if unknown:
        p.error(f"unknown kinds {sorted(unknown)}; expected some of {', '.join(targets.KINDS)}")
    preload()
    work = Path(args.work or tempfile.mkdtemp(prefix="splitrender-fuzz-")).resolve()
    try:
        if args.replay:
            kind, _, index = args.replay.partition(":")
            build_seeds(work / "seeds")
            r = run_one(kind, int(index), seed, work / "seeds", work / "cases")
            print(json.dumps(asdict(r), indent=2))
            print(f"case files: {work / 'cases' / f'{kind}-{index}'}")
            return 0 if Outcome(r.outcome).good else 1
        results, seconds = run_all(0 if args.pinned else cases, seed, kinds, work,
                                   pinned=args.ci or args.pinned)
    finally:
        if args.work is None and not args.replay:
            shutil.rmtree(work, ignore_errors=True)
    shown = ["python -m tests.fuzz", f"--cases {cases}", f"--seed {seed}"]
    if args.kinds != ",".join(targets.KINDS):
        shown.append(f"--kinds {args.kinds}")
    if args.out:
        shown.append(f"--out {args.out}")
    text = report(results, seed, " ".join(shown), seconds)
    if args.out:
        args.out.write_text(text)
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in results], indent=1))
    print(table(results))
    bad = sum(not Outcome(r.outcome).good for r in results)
    print(f"{len(results)} cases in {seconds:.0f} s, {bad} with a bad outcome", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
