#!/usr/bin/env python3
"""Checks the invariants of ARCHITECTURE.md that the compiler alone does not.

1. Layers: each workspace crate depends (normal dependencies) only on the skybake crates below it;
   nothing depends on the harness, not even for tests.
2. Purity: the physics, engine and render crates do no I/O (no std::fs, std::net, std::process,
   tokio); outside the store only the harness (process statistics, probes) touches files.
3. No import circle between the modules of a crate (`crate::` and `super::` paths, test modules
   left out; a module naming an item of its own ancestors is not a circle).

Run from the repository root: `python3 tools/check_layers.py`. Exit status 1 lists what is wrong.
"""

import collections
import glob
import json
import os
import re
import subprocess
import sys

# Each crate and the skybake crates it may depend on (the layers, bottom to top).
ALLOWED = {
    "skybake-physics": set(),
    "skybake-engine": {"skybake-physics"},
    "skybake-render": {"skybake-physics", "skybake-engine"},
    "skybake-store": {"skybake-physics"},
    "skybake-lut": {"skybake-physics", "skybake-engine"},
    "skybake-product": {"skybake-physics", "skybake-engine", "skybake-render", "skybake-store",
                        "skybake-lut"},
    "skybake-job": {"skybake-physics", "skybake-engine", "skybake-render", "skybake-store",
                    "skybake-lut", "skybake-product"},
    "skybake-service": {"skybake-physics", "skybake-engine", "skybake-render", "skybake-store",
                        "skybake-lut", "skybake-product", "skybake-job"},
    "skybake-harness": {"skybake-physics", "skybake-engine", "skybake-render", "skybake-store",
                        "skybake-lut", "skybake-product"},
    "skybake": {"skybake-physics", "skybake-engine", "skybake-render", "skybake-store",
                "skybake-lut", "skybake-product", "skybake-job", "skybake-service"},
}
PURE = ["crates/physics/src", "crates/engine/src", "crates/render/src", "crates/lut/src"]
IO_PATTERN = re.compile(r"\bstd::(fs|net|process)\b|\btokio::|\bFile::(open|create)\b")
FS_PATTERN = re.compile(r"\bstd::fs\b|\bFile::(open|create)\b")
# Where files may be touched: the store, and the harness (outside the product).
FS_ALLOWED = ("crates/store/", "crates/harness/")


def code_of(path):
    """The file's code without comments and without its test module."""
    text = open(path, encoding="utf-8").read()
    text = re.sub(r"//[^\n]*", "", text)
    return re.split(r"#\[cfg\(test\)\]\s*mod tests", text)[0]


def check_layers(problems):
    meta = json.loads(subprocess.run(
        ["cargo", "metadata", "--format-version", "1", "--no-deps", "--offline"],
        check=True, capture_output=True, text=True).stdout)
    names = {p["name"] for p in meta["packages"]}
    for unknown in sorted(names - set(ALLOWED)):
        problems.append(f"{unknown}: a workspace crate with no place in the layers (tools/check_layers.py)")
    for p in meta["packages"]:
        for d in p["dependencies"]:
            if not d["name"].startswith("skybake"):
                continue
            if d["name"] == "skybake-harness":
                problems.append(f"{p['name']} depends on the harness, which nothing may depend on")
                continue
            if d["kind"] == "dev":
                continue
            if d["name"] not in ALLOWED.get(p["name"], set()):
                problems.append(f"{p['name']} depends on {d['name']}, which is not below it")


def check_io(problems):
    for root in PURE:
        for path in glob.glob(f"{root}/**/*.rs", recursive=True):
            for m in IO_PATTERN.finditer(code_of(path)):
                problems.append(f"{path}: I/O in a pure crate ({m.group(0)})")
    for path in glob.glob("crates/*/src/**/*.rs", recursive=True) + glob.glob("src/**/*.rs", recursive=True):
        if path.startswith(FS_ALLOWED):
            continue
        for m in FS_PATTERN.finditer(code_of(path)):
            problems.append(f"{path}: touches files outside the store ({m.group(0)})")


def module_of(root, path):
    parts = os.path.relpath(path, root)[:-3].split(os.sep)
    if parts[-1] in ("mod", "lib", "main"):
        parts = parts[:-1]
    return tuple(parts)


def check_cycles(problems):
    for root in sorted(glob.glob("crates/*/src")) + ["src"]:
        files = glob.glob(f"{root}/**/*.rs", recursive=True)
        modules = {module_of(root, p): p for p in files}
        edges = collections.defaultdict(set)
        for m, path in modules.items():
            code = code_of(path)
            refs = {tuple(r.split("::")) for r in re.findall(r"\bcrate::((?:\w+::)*\w+)", code)}
            for group in re.findall(r"\buse crate::\{([^;]*)\}", code, re.S):
                refs |= {tuple(r.split("::")) for r in re.findall(r"\w+(?:::\w+)*", group)}
            for ups, rest in re.findall(r"\b((?:super::)+)((?:\w+::)*\w+)", code):
                base = m[: len(m) - ups.count("super::")]
                refs.add(tuple(base) + tuple(rest.split("::")))
            for r in refs:
                target = next((r[:i] for i in range(len(r), 0, -1) if r[:i] in modules), None)
                if target and target != m and m[: len(target)] != target:
                    edges[m].add(target)
        # Tarjan's strongly connected components.
        index, low, stack, on_stack, counter = {}, {}, [], set(), [0]

        def visit(v):
            index[v] = low[v] = counter[0]
            counter[0] += 1
            stack.append(v)
            on_stack.add(v)
            for w in edges[v]:
                if w not in index:
                    visit(w)
                    low[v] = min(low[v], low[w])
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    names = sorted("::".join(c) or "lib" for c in component)
                    problems.append(f"{root}: import circle between modules {', '.join(names)}")

        sys.setrecursionlimit(10000)
        for v in list(modules):
            if v not in index:
                visit(v)


def main():
    problems = []
    check_layers(problems)
    check_io(problems)
    check_cycles(problems)
    for p in problems:
        print(p, file=sys.stderr)
    if problems:
        sys.exit(1)
    print("layers, purity and module graph: ok")


if __name__ == "__main__":
    main()
