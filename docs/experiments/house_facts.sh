#!/usr/bin/env bash
# Recomputes the facts of docs/experiments/house_facts.md (issue 25): the crate graph, the
# longest function and file of the non-test code, and the pairs of places sharing six or more
# lines (`duplicates`), at a base commit and at HEAD.
#
# Usage: docs/experiments/house_facts.sh [BASE]   (BASE defaults to 59dae13; run from anywhere
# inside the repository; needs git, python3, tar and `duplicates` on PATH; takes ~4 minutes,
# the duplicate scan being given 120 s per tree).
set -euo pipefail
BASE=${1:-59dae13}
ROOT=$(git rev-parse --show-toplevel)
cd "$ROOT"
TMP=/tmp/house_$BASE
rm -rf "$TMP" && mkdir -p "$TMP"
git archive "$BASE" | tar -x -C "$TMP"

# One Python program for the graph and the lengths; it reads a tree given as a folder.
cat > /tmp/house_facts_scan.py <<'PY'
import glob, os, re, sys

ORDER = ["data", "nn", "render", "model", "train", "edit", "eval", "report", "cli"]

def crate_graph(root):
    graph = {}
    for toml in sorted(glob.glob(os.path.join(root, "crates/*/Cargo.toml"))):
        crate = os.path.basename(os.path.dirname(toml))
        deps, section = [], None
        for line in open(toml):
            s = line.strip()
            if s.startswith("["):
                section = s
                continue
            m = re.match(r"i2sdf-([a-z]+)\b", s)
            if section == "[dependencies]" and m:
                deps.append(m.group(1))
        graph[crate] = sorted(deps, key=lambda c: (ORDER + ["synth"]).index(c))
    return graph

def one_way(graph):
    """Whether the graph is acyclic, and the edges (synth aside) that point against the order
    data → nn → render → model → train → edit → eval → report → cli."""
    seen, stack = set(), set()
    def cyclic(c):
        if c in stack:
            return True
        if c in seen:
            return False
        seen.add(c); stack.add(c)
        r = any(cyclic(d) for d in graph.get(c, []))
        stack.discard(c)
        return r
    acyclic = not any(cyclic(c) for c in graph)
    against = []
    for c, ds in graph.items():
        for d in ds:
            if c in ORDER and d in ORDER and ORDER.index(d) >= ORDER.index(c):
                against.append(f"{c}→{d}")
    return acyclic, against

def tokens_mask(text):
    """The text with comments, strings and char literals blanked (newlines kept)."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i)); i = j
        elif text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j): depth += 1; j += 2
                elif text.startswith("*/", j): depth -= 1; j += 2
                else: j += 1
            out.append(re.sub(r"[^\n]", " ", text[i:j])); i = j
        elif re.match(r'b?r#*"', text[i:i + 10]) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            m = re.match(r'b?r(#*)"', text[i:])
            end = text.find('"' + m.group(1), i + m.end())
            j = n if end < 0 else end + 1 + len(m.group(1))
            out.append(re.sub(r"[^\n]", " ", text[i:j])); i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            j += 1
            out.append(re.sub(r"[^\n]", " ", text[i:j])); i = j
        elif c == "'":
            m = re.match(r"'(\\.[^']*|[^\\'\n])'", text[i:])
            if m:
                out.append(" " * m.end()); i += m.end()
            else:
                out.append(c); i += 1  # a lifetime
        else:
            out.append(c); i += 1
    return "".join(out)

def item_end(masked, start):
    """Index just past the item starting at `start`: its matching `}`, or a `;` before any `{`
    at bracket depth 0 (a declaration). Returns (end, has_body)."""
    depth, i = 0, start
    while i < len(masked):
        c = masked[i]
        if c in "([":
            depth += 1
        elif c in ")]":
            depth -= 1
        elif c == ";" and depth == 0:
            return i + 1, False
        elif c == "{" and depth == 0:
            braces = 0
            while i < len(masked):
                if masked[i] == "{": braces += 1
                elif masked[i] == "}":
                    braces -= 1
                    if braces == 0:
                        return i + 1, True
                i += 1
            return len(masked), True
        i += 1
    return len(masked), False

TEST_ATTR = re.compile(r"#\[cfg\((test|any\(test\b[^\]]*)\)\]")
FN = re.compile(r"^\s*(pub(\([^)]*\))?\s+)?((const|async|unsafe|default)\s+)*(extern\s+\"[^\"]*\"\s+)?fn\s+(\w+)", re.M)

def scan(root):
    files = sorted(glob.glob(os.path.join(root, "crates/*/src/**/*.rs"), recursive=True))
    test_files, test_ranges, masks = set(), {}, {}
    for f in files:
        text = open(f, encoding="utf-8").read()
        masked = tokens_mask(text)
        masks[f] = (text, masked)
        ranges = []
        for m in TEST_ATTR.finditer(masked):
            # The item the attribute gates: skip further attributes, then to its end.
            j = m.end()
            rest = masked[j:]
            path = None
            while True:
                a = re.match(r"\s*#\[([^\]]*)\]", rest)
                if not a:
                    break
                p = re.search(r'path\s*=\s*', a.group(1))
                if p:
                    path = re.search(r'#\[path\s*=\s*"([^"]+)"', text[j:j + a.end()]).group(1)
                j += a.end(); rest = masked[j:]
            end, body = item_end(masked, j)
            ranges.append((m.start(), end))
            d = re.match(r"\s*(pub(\([^)]*\))?\s+)?mod\s+(\w+)\s*;", masked[j:end])
            if d and not body:
                here = os.path.dirname(f)
                stem = os.path.splitext(os.path.basename(f))[0]
                base = here if stem in ("lib", "main", "mod") else os.path.join(here, stem)
                for cand in ([os.path.join(here, path)] if path else
                             [os.path.join(base, d.group(3) + ".rs"), os.path.join(base, d.group(3), "mod.rs")]):
                    test_files.add(os.path.normpath(cand))
        test_ranges[f] = ranges
    fns, file_lines = [], []
    for f in files:
        if os.path.normpath(f) in test_files:
            continue
        text, masked = masks[f]
        rel = os.path.relpath(f, root)
        file_lines.append((text.count("\n") + (0 if text.endswith("\n") else 1), rel))
        for m in FN.finditer(masked):
            s = m.start() + len(m.group(0)) - len(m.group(0).lstrip())
            if any(a <= s < b for a, b in test_ranges[f]):
                continue
            end, body = item_end(masked, s)
            if not body:
                continue
            first = masked.count("\n", 0, s) + 1
            last = masked.count("\n", 0, end - 1) + 1
            fns.append((last - first + 1, f"{rel}:{first}", m.group(6)))
    fns.sort(key=lambda t: -t[0]); file_lines.sort(key=lambda t: -t[0])
    return fns, file_lines, len(files) - len([f for f in files if os.path.normpath(f) in test_files])

root, label = sys.argv[1], sys.argv[2]
if label == "HEAD":
    g = crate_graph(root)
    acyclic, against = one_way(g)
    print("## crate graph ([dependencies], i2sdf crates only)")
    for c in ORDER + ["synth"]:
        print(f"  {c:7s} → {', '.join(g.get(c, [])) or '(none)'}")
    print(f"  acyclic: {acyclic}; edges against data → nn → render → model → train → edit → eval → report → cli: {', '.join(against) or 'none'}")
fns, files, n = scan(root)
print(f"## {label}: {n} non-test files, {len(fns)} functions with a body")
print(f"  longest function: {fns[0][2]} {fns[0][1]} ({fns[0][0]} lines)")
print(f"  longest file: {files[0][1]} ({files[0][0]} lines)")
if label == "HEAD":
    print("  top 5 functions:")
    for length, where, name in fns[:5]:
        print(f"    {length:4d}  {name}  {where}")
PY

python3 /tmp/house_facts_scan.py "$ROOT" HEAD
python3 /tmp/house_facts_scan.py "$TMP" "$BASE"
echo "## duplicates --seconds 120 (first line)"
echo "  $BASE: $(duplicates --repo "$TMP" --seconds 120 | head -1)"
echo "  HEAD (working tree): $(duplicates --repo "$ROOT" --seconds 120 | head -1)"
