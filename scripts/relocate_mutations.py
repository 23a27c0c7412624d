#!/usr/bin/env python3
"""Re-anchors tests/mutations/*.patch after code moved (files renamed, functions moved between
files): each hunk's old text (context and removed lines) is searched for, verbatim, in the
patch's own file if it still exists, else in every tracked file of the same extension; it must
occur exactly once. The hunk is applied there, `git diff` of that file becomes the new patch
(the patch's leading comment lines are kept) and the file is restored. Patches that still apply
are left alone. Usage: scripts/relocate_mutations.py [PATCH ...] (default: all)."""
import pathlib, re, subprocess, sys

root = pathlib.Path(__file__).resolve().parent.parent

def git(*a, **kw):
    return subprocess.run(["git", *a], cwd=root, check=True, capture_output=True, text=True, **kw).stdout

def parse(text):
    lines = text.splitlines(keepends=True)
    head, i = [], 0
    while not lines[i].startswith("--- "):
        head.append(lines[i]); i += 1
    path = lines[i][len("--- a/"):].strip()
    hunks, cur = [], None
    for l in lines[i + 2:]:
        if l.startswith("@@"):
            cur = ([], []); hunks.append(cur); continue
        tag, body = l[:1], l[1:]
        if tag in (" ", "-"): cur[0].append(body)
        if tag in (" ", "+"): cur[1].append(body)
    return head, path, [("".join(o), "".join(n)) for o, n in hunks]

def relocate(patch):
    if subprocess.run(["git", "apply", "--check", str(patch)], cwd=root, capture_output=True).returncode == 0:
        return "ok"
    head, path, hunks = parse(patch.read_text())
    ext = pathlib.Path(path).suffix
    cands = [path] if (root / path).exists() else [f for f in git("ls-files").split() if f.endswith(ext)]
    hits = [f for f in cands if all((root / f).read_text().count(o) == 1 for o, _ in hunks)]
    if len(hits) != 1:
        return f"FAILED ({len(hits)} files hold every hunk exactly once)"
    f = root / hits[0]
    orig = f.read_text()
    new = orig
    for o, n in hunks: new = new.replace(o, n)
    f.write_text(new)
    try:
        diff = git("diff", "--", hits[0])
    finally:
        f.write_text(orig)
    diff = diff[diff.index("--- a/"):]
    patch.write_text("".join(head) + diff)
    return f"moved to {hits[0]}"

pats = [pathlib.Path(p).resolve() for p in sys.argv[1:]] or sorted((root / "tests/mutations").glob("*.patch"))
bad = 0
for p in pats:
    r = relocate(p)
    bad += r.startswith("FAILED")
    print(f"{p.name}: {r}")
sys.exit(1 if bad else 0)
