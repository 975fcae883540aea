#!/usr/bin/env python3
# Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
"""Every Debian package whose files the build and the scripts use must be installed on a fresh
Debian 12 minbase system by scripts/setup.sh: named in its PKGS list, or pulled in by a Depends /
Pre-Depends chain from it (apt installs with --no-install-recommends, so a Recommends is not
enough), or part of minbase (Essential or Priority: required, and apt).

The files used, read off this machine's build and the sources:
  - the headers in the compilers' dependency files (build/ and the fuzz build, build/fuzz);
  - what each link line hands the linker (the compiler driver's -### expansion of link.txt: the
    libraries, and the sanitizer and libFuzzer runtimes of the fuzz build);
  - the Python modules the scripts and tests import (an import guarded by `except ImportError` is
    optional); a script run by a shell script that installs its own packages (training) may use
    those;
  - the commands the shell scripts run (first word of each command, after wrappers such as
    timeout or xvfb-run), and the nodes and includes of the launch and rostest files.
Each file is mapped to its package with dpkg -S. Scope: what the build and the tests exercise on
this machine; scripts/fresh_debian_check.sh runs both README commands on a real minbase system.

Usage: check_setup_packages.py SOURCE_DIR BUILD_DIR [--without PKG]...
  --without PKG   check as if set-up did not list PKG (the suite uses it to prove the check fails)
Exit 0: covered; 1: a package is missing (each listed with the files that need it); 77: the
fuzz build is absent (the rest was checked and passed), so its runtimes were not checked.
"""
import argparse
import ast
import importlib.util
import os
import re
import shlex
import subprocess
import sys

DEFAULT_LIB_DIRS = ["/usr/lib/x86_64-linux-gnu", "/lib/x86_64-linux-gnu", "/usr/lib", "/lib"]
SYSTEM_PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"
# Build trees' folders that hold no build (the fresh system's root, outputs, training runs).
PRUNE = {"fresh_debian", "devel", "test_results", "training", "demo", "corpus", "crashes", "seeds"}
# Words a shell script runs only on a machine that lacks root, to get it: not set-up's to install.
NOT_SETUPS = {"sudo": "used only by a user who is not root, to run apt-get"}
SHELL_WRAPPERS = {"sudo", "$SUDO", "env", "exec", "nohup", "setsid", "nice", "command", "time", "stdbuf", "!"}


def setup_packages(source):
    text = open(os.path.join(source, "scripts", "setup.sh")).read()
    m = re.search(r"^PKGS=\((.*?)^\)", text, re.S | re.M)
    if not m:
        sys.exit("check_setup_packages: no PKGS=( ... ) list in scripts/setup.sh")
    return {w for line in m.group(1).splitlines() for w in line.split("#")[0].split()}


def own_installs(source):
    """Shell scripts that install packages of their own (apt-get install lines): script -> packages."""
    out = {}
    for name in sorted(os.listdir(os.path.join(source, "scripts"))):
        if not name.endswith(".sh") or name == "setup.sh":
            continue
        for line in open(os.path.join(source, "scripts", name)):
            if "apt-get install" in line and not line.lstrip().startswith("#"):
                words = line.split("apt-get install", 1)[1].split(">")[0].split("||")[0].split()
                out.setdefault(name, set()).update(w for w in words if re.fullmatch(r"[a-z0-9][a-z0-9.+-]+", w))
    return out


# ---- the Debian side: installed packages, their Depends closure, file owners -------------------
def installed_packages():
    fmt = "${Package}\t${db:Status-Abbrev}\t${Essential}\t${Priority}\t${Pre-Depends}\t${Depends}\t${Provides}\n"
    out = subprocess.run(["dpkg-query", "-W", "-f", fmt], capture_output=True, text=True, check=True).stdout
    pkgs, providers = {}, {}
    for line in out.splitlines():
        name, status, essential, priority, pre, dep, provides = (line.split("\t") + [""] * 7)[:7]
        if not status.startswith("ii"):
            continue
        pkgs[name] = {"base": essential == "yes" or priority == "required" or name == "apt",
                      "deps": [g for g in (pre + "," + dep).split(",") if g.strip()]}
        for p in provides.split(","):
            p = p.split("(")[0].strip()
            if p:
                providers.setdefault(p, set()).add(name)
    return pkgs, providers


def bare(name):
    return name.split("(")[0].strip().split(":")[0]


def closure(roots, pkgs, providers):
    """What apt --no-install-recommends installs for roots: Depends and Pre-Depends, the first
    alternative of each (apt's choice), a virtual package by its installed providers."""
    seen, todo = set(), list(roots)
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        seen.add(p)
        for group in pkgs.get(p, {}).get("deps", []):
            alts = [bare(a) for a in group.split("|")]
            if any(a in seen for a in alts):
                continue
            first = alts[0]
            if first in pkgs or first not in providers:
                todo.append(first)
            else:
                todo.extend(providers[first])
    return seen


def owners(paths):
    """File -> set of packages (dpkg -S), trying the merged-/usr spellings of each path."""
    variants = {}
    for p in paths:
        cands = {p, os.path.realpath(p)}
        for c in list(cands):
            if c.startswith("/usr/") and c.split("/")[2] in ("lib", "lib64", "bin", "sbin"):
                cands.add(c[4:])
            elif c.split("/")[1] in ("lib", "lib64", "bin", "sbin"):
                cands.add("/usr" + c)
        variants[p] = cands
    allv = sorted({c for cs in variants.values() for c in cs})
    found = {}
    for i in range(0, len(allv), 2000):
        r = subprocess.run(["dpkg-query", "-S"] + allv[i:i + 2000], capture_output=True, text=True)
        for line in r.stdout.splitlines():
            if line.startswith("diversion ") or ": " not in line:
                continue
            names, path = line.split(": ", 1)
            found.setdefault(path, set()).update(bare(n) for n in names.split(","))
    return {p: set().union(*(found.get(c, set()) for c in cs)) for p, cs in variants.items()}


# ---- what the build uses ------------------------------------------------------------------------
def build_dirs(build):
    for root, dirs, files in os.walk(build):
        dirs[:] = [d for d in dirs if d not in PRUNE and not os.path.islink(os.path.join(root, d))]
        yield root, files


def depfile_headers(build, inside):
    used = set()
    for root, files in build_dirs(build):
        for f in files:
            if f.endswith(".o.d"):
                text = open(os.path.join(root, f), errors="replace").read().replace("\\\n", " ")
                for tok in text.split():
                    if tok.startswith("/") and not tok.endswith(":"):
                        p = os.path.normpath(tok)
                        if not inside(p):
                            used.add(p)
    return used


def link_inputs(build, inside):
    """The files each link.txt hands the linker, from the driver's own expansion (-###)."""
    used, missing = set(), set()
    for root, files in build_dirs(build):
        if "link.txt" not in files:
            continue
        cwd = os.path.dirname(root)  # make runs link.txt from the target's build folder
        while os.path.basename(cwd) == "CMakeFiles" or cwd.endswith(".dir"):
            cwd = os.path.dirname(cwd)
        for line in open(os.path.join(root, "link.txt")):
            words = shlex.split(line)
            if not words or not re.search(r"(g\+\+|c\+\+|clang\+\+|gcc|cc)(-[0-9.]+)?$", words[0]):
                continue
            r = subprocess.run(words + ["-###"], cwd=cwd, capture_output=True, text=True)
            ld = [l for l in r.stderr.splitlines() if l.startswith(" ") and ("collect2" in l or "/ld" in l)]
            if not ld:
                continue
            toks = shlex.split(ld[-1])
            libdirs = [t[2:] for t in toks if t.startswith("-L")] + DEFAULT_LIB_DIRS
            for t in toks[1:]:
                if t.startswith("-l") and len(t) > 2:
                    name = t[2:]
                    cands = [os.path.join(d, n) for d in libdirs
                             for n in ((name[1:],) if name.startswith(":") else ("lib%s.so" % name, "lib%s.a" % name))]
                    hit = next((c for c in cands if os.path.exists(c)), None)
                    (used.add(os.path.normpath(hit)) if hit else missing.add("-l" + name))
                elif t.startswith("/") and re.search(r"\.(a|so|o)(\.[0-9.]+)?$", t):
                    p = os.path.normpath(os.path.join(cwd, t))
                    if inside(p):
                        continue
                    (used.add(p) if os.path.exists(p) else missing.add(p))
    return used, missing


# ---- what the scripts use -------------------------------------------------------------------------
def python_files(source):
    for top in ("scripts", "test", ".ci"):
        for root, dirs, files in os.walk(os.path.join(source, top)):
            dirs[:] = [d for d in dirs if d != "__pycache__"]
            for f in files:
                path = os.path.join(root, f)
                if f.endswith(".py"):
                    yield path


def imports(path, text=None):
    """(required, optional) top-level module names; optional: under a try that catches ImportError."""
    tree = ast.parse(open(path).read() if text is None else text, path)
    required, optional = set(), set()

    def catches_import_error(node):
        for h in node.handlers:
            names = [h.type] if not isinstance(h.type, ast.Tuple) else list(h.type.elts)
            if h.type is None or any(isinstance(n, ast.Name) and n.id in ("ImportError", "ModuleNotFoundError", "Exception")
                                     for n in names):
                return True
        return False

    def visit(node, guarded):
        if isinstance(node, ast.Try) and catches_import_error(node):
            for child in node.body:
                visit(child, True)
            for child in node.handlers + node.orelse + node.finalbody:
                visit(child, guarded)
            return
        if isinstance(node, ast.Import):
            for a in node.names:
                (optional if guarded else required).add(a.name.split(".")[0])
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            (optional if guarded else required).add(node.module.split(".")[0])
        for child in ast.iter_child_nodes(node):
            visit(child, guarded)

    visit(tree, False)
    return required, optional - required


def shell_files(source):
    yield os.path.join(source, ".ci", "run")
    for top in ("scripts", "test"):
        for root, _, files in os.walk(os.path.join(source, top)):
            for f in files:
                if f.endswith(".sh"):
                    yield os.path.join(root, f)


def shell_commands(path):
    """The first word of each command (a rough reading: quotes blanked but for their $(...),
    comments skipped), and the Python fed to python3 in heredocs (their imports are checked)."""
    words, heredoc, snippets = set(), None, []

    def read(line):
        line = re.sub(r'"(?:[^"\\]|\\.)*"', '""', line)
        line = re.sub(r"'[^']*'", "''", line)
        line = re.sub(r"(^|\s)#.*$", "", line)
        for seg in re.split(r"\|\||&&|[|;&({}`]|\$\(|\bthen\b|\bdo\b|\belse\b|\bif\b|\bwhile\b|\buntil\b", line):
            toks = seg.split()
            while toks and (re.fullmatch(r"\w+=.*", toks[0]) or toks[0] in SHELL_WRAPPERS or toks[0].startswith("-")):
                toks.pop(0)
            if toks and toks[0] in ("timeout", "xvfb-run"):
                words.add(toks[0])
                toks.pop(0)
                while toks and (toks[0].startswith("-") or re.fullmatch(r"[0-9.]+[smh]?", toks[0]) or toks[0] == '""'):
                    toks.pop(0)
            if toks and re.fullmatch(r"[A-Za-z][\w.+-]*|/(usr/)?s?bin/[\w.+-]+", toks[0]):
                words.add(toks[0])

    for raw in open(path, errors="replace"):
        if heredoc:
            if raw.strip() == heredoc[0]:
                if heredoc[1]:
                    snippets.append("".join(heredoc[2]))
                heredoc = None
            else:
                heredoc[2].append(raw)
            continue
        m = re.search(r"<<-?\s*['\"]?(\w+)['\"]?", raw)
        if m:
            heredoc = (m.group(1), "python3" in raw[:m.start()], [])
        read(raw)
        for inner in re.findall(r"\$\(([^()]*)\)", raw):
            read(inner)
    return words, snippets


def which(word):
    if word.startswith("/"):
        return word if os.path.isfile(word) else None
    for d in SYSTEM_PATH.split(":"):
        p = os.path.join(d, word)
        if os.path.isfile(p) and os.access(p, os.X_OK):
            return p
    return None


def ros_files(source):
    """Executables and package folders that the launch/rostest files name (other packages')."""
    used, missing = set(), set()
    files = [os.path.join(d, f) for top in ("launch", "test/ros") for d, _, fs in os.walk(os.path.join(source, top))
             for f in fs if f.endswith((".launch", ".test", ".xml"))]
    for path in files:
        text = open(path).read()
        nodes = re.findall(r'<node\b[^>]*?pkg="([^"$]+)"[^>]*?type="([^"$]+)"', text)
        nodes += [(pkg, typ) for typ, pkg in re.findall(r'<node\b[^>]*?type="([^"$]+)"[^>]*?pkg="([^"$]+)"', text)]
        for pkg, typ in nodes:
            if pkg == "endo_guidance":
                continue
            cands = ["/usr/lib/%s/%s" % (pkg, typ), "/usr/share/%s/scripts/%s" % (pkg, typ), "/usr/bin/" + typ]
            hit = next((c for c in cands if os.path.exists(c)), None)
            (used.add(hit) if hit else missing.add("%s/%s (node in %s)" % (pkg, typ, os.path.relpath(path, source))))
        for pkg in re.findall(r"\$\(find ([\w]+)\)", text):
            if pkg != "endo_guidance":
                p = "/usr/share/%s/package.xml" % pkg
                (used.add(p) if os.path.exists(p) else missing.add("$(find %s) in %s" % (pkg, os.path.relpath(path, source))))
    return used, missing


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source")
    ap.add_argument("build")
    ap.add_argument("--without", action="append", default=[], help="check as if set-up did not list this package")
    a = ap.parse_args()
    source, build = os.path.realpath(a.source), os.path.realpath(a.build)

    def inside(p):
        return p.startswith(source + "/") or p.startswith(build + "/")

    listed = setup_packages(source) - set(a.without)
    pkgs, providers = installed_packages()
    have = closure(listed | {p for p, v in pkgs.items() if v["base"]}, pkgs, providers)

    need = {}  # file or name -> why (for the report)
    problems = []
    if not os.path.isdir(os.path.join(build, "CMakeFiles")):
        sys.exit("check_setup_packages: no build at %s (scripts/setup.sh builds it)" % build)
    fuzz = os.path.join(build, "fuzz")
    fuzz_built = os.path.isdir(os.path.join(fuzz, "CMakeFiles"))
    headers = depfile_headers(build, inside)
    links, link_missing = link_inputs(build, inside)
    for p in headers:
        need[p] = "included by the build"
    for p in links:
        need[p] = "linked by the build"
    problems += ["the build links %s, which no installed file provides" % m for m in sorted(link_missing)]

    scripts_own = own_installs(source)
    allowed_extra = {}  # python file -> packages its calling script installs itself
    for script, extra in scripts_own.items():
        text = open(os.path.join(source, "scripts", script)).read()
        for py in python_files(source):
            if os.path.basename(py) in text:
                allowed_extra.setdefault(py, set()).update(extra)
    local = {os.path.splitext(os.path.basename(p))[0] for p in python_files(source)} | {"endo_guidance"}
    extra_ok = {}  # file -> packages allowed for it beyond set-up's

    def check_module(mod, path, rel, extra):
        spec = importlib.util.find_spec(mod)
        if spec is None:
            if not extra:  # else installed by its own script (not on this machine now)
                problems.append("%s imports %s, which is not installed here" % (rel, mod))
            return
        origin = spec.origin or (list(spec.submodule_search_locations or []) or [None])[0]
        if not origin or origin in ("built-in", "frozen"):
            return  # the interpreter's own
        need.setdefault(origin, "imported by %s (%s)" % (rel, mod))
        extra_ok.setdefault(origin, set()).update(extra)

    for py in python_files(source):
        for mod in sorted(imports(py)[0] - local - set(sys.builtin_module_names)):
            check_module(mod, py, os.path.relpath(py, source), allowed_extra.get(py, set()))
    for sh in shell_files(source):
        rel = os.path.relpath(sh, source)
        own = scripts_own.get(os.path.basename(sh), set())
        words, snippets = shell_commands(sh)
        for text in snippets:
            for mod in sorted(imports(sh, text)[0] - local - set(sys.builtin_module_names)):
                check_module(mod, sh, rel, set())
        for w in sorted(words):
            if w in NOT_SETUPS:
                continue
            p = which(w)
            if p:
                need.setdefault(p, "run by %s (%s)" % (rel, w))
                extra_ok.setdefault(p, set()).update(own)
    ros_used, ros_missing = ros_files(source)
    for p in ros_used:
        need.setdefault(p, "named by a launch or rostest file")
    problems += ["%s: not installed here" % m for m in sorted(ros_missing)]

    owner = owners(need)
    by_package = {}
    for p, why in sorted(need.items()):
        pk = owner.get(p, set())
        if not pk:
            if p.startswith(("/usr/", "/lib", "/bin", "/sbin", "/etc/")):
                problems.append("%s (%s) belongs to no Debian package" % (p, why))
            continue
        if pk & (have | extra_ok.get(p, set())):
            continue
        by_package.setdefault(" or ".join(sorted(pk)), []).append("%s (%s)" % (p, why))
    for pk, files in sorted(by_package.items()):
        problems.append("package %s is used but not installed by scripts/setup.sh or a Depends of it: %s%s" %
                        (pk, "; ".join(files[:3]), " and %d more" % (len(files) - 3) if len(files) > 3 else ""))

    print("check_setup_packages: %d listed packages (%d with their Depends and minbase); %d headers, %d link inputs, "
          "%d other files used%s" % (len(listed), len(have), len(headers), len(links), len(need) - len(headers) - len(links),
                                    "" if fuzz_built else "; no fuzz build"))
    if problems:
        for p in problems:
            print("  MISSING: " + p)
        return 1
    if not fuzz_built:
        print("check_setup_packages: SKIPPED the fuzz build's runtimes (no %s: scripts/fuzz.sh build)" % fuzz)
        return 77
    print("check_setup_packages: every package used is installed by set-up")
    return 0


if __name__ == "__main__":
    sys.exit(main())
