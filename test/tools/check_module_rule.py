#!/usr/bin/python3
"""The core's dependency rule (docs/architecture.md): what each module may include.

  geometry    Eigen only
  perception  OpenCV, Eigen; geometry
  control     ViSP, Eigen; geometry
  sim         OpenCV, Eigen; geometry
  pipeline    OpenCV, Eigen; perception, geometry
No module includes ROS, a message header, io/ or ros/. Every core file must sit in a module.
Usage: check_module_rule.py REPO_ROOT. Exit 1 with each violation; the rule is first checked on a
small tree with planted violations, so that a checker that finds nothing fails too.
"""
import os
import re
import sys
import tempfile

MODULES = {
    "geometry": ({"geometry"}, {"eigen"}),
    "perception": ({"perception", "geometry"}, {"eigen", "opencv"}),
    "control": ({"control", "geometry"}, {"eigen", "visp"}),
    "sim": ({"sim", "geometry"}, {"eigen", "opencv"}),
    "pipeline": ({"pipeline", "perception", "geometry"}, {"eigen", "opencv"}),
}
EXTERNAL = {"eigen": re.compile(r"^(Eigen|unsupported/Eigen)/"), "opencv": re.compile(r"^opencv2/"),
            "visp": re.compile(r"^visp3/")}
# Anything else in <...> must be the standard library or a compiler intrinsic header.
SYSTEM = re.compile(r"^([a-z_]+|[a-z]+intrin\.h|immintrin\.h|emmintrin\.h|filesystem)$")
INCLUDE = re.compile(r'^\s*#\s*include\s*([<"])([^>"]+)[>"]')


def check(root):
    bad = []
    for top in (os.path.join(root, "include", "endo_guidance"), os.path.join(root, "src")):
        for mod in MODULES:
            d = os.path.join(top, mod)
            for dirpath, _, files in os.walk(d):
                for f in files:
                    bad += check_file(os.path.join(dirpath, f), mod, root)
    if os.path.isdir(os.path.join(root, "src", "core")) or os.path.isdir(os.path.join(root, "include", "endo_guidance", "core")):
        bad.append("core/: every core file belongs to a module (%s)" % ", ".join(MODULES))
    return bad


def check_file(path, mod, root):
    allowed_mods, allowed_ext = MODULES[mod]
    rel = os.path.relpath(path, root)
    bad = []
    for n, line in enumerate(open(path, encoding="utf-8", errors="replace"), 1):
        m = INCLUDE.match(line)
        if not m:
            continue
        what = m.group(2)
        own = re.match(r"^endo_guidance/(\w+)/", what)
        if own:
            if own.group(1) not in allowed_mods:
                bad.append("%s:%d: %s may not include %s" % (rel, n, mod, what))
            continue
        if m.group(1) == '"':
            bad.append("%s:%d: %s: a quoted include outside the package's modules" % (rel, n, what))
            continue
        lib = [k for k, r in EXTERNAL.items() if r.match(what)]
        if lib:
            if lib[0] not in allowed_ext:
                bad.append("%s:%d: %s may not depend on %s (%s)" % (rel, n, mod, lib[0], what))
        elif not SYSTEM.match(what):
            bad.append("%s:%d: %s may not include <%s>" % (rel, n, mod, what))
    return bad


def self_test():
    with tempfile.TemporaryDirectory() as t:
        planted = {
            "include/endo_guidance/geometry/a.h": '#include <opencv2/core.hpp>\n#include <Eigen/Core>\n',
            "src/geometry/a.cpp": '#include "endo_guidance/perception/b.h"\n#include <vector>\n',
            "src/perception/b.cpp": '#include <ros/ros.h>\n#include "endo_guidance/geometry/a.h"\n',
            "src/control/c.cpp": '#include <visp3/vs/vpServo.h>\n#include "endo_guidance/sim/d.h"\n',
            "src/core/e.cpp": "\n",
        }
        for p, text in planted.items():
            os.makedirs(os.path.dirname(os.path.join(t, p)), exist_ok=True)
            open(os.path.join(t, p), "w").write(text)
        found = check(t)
        want = ["geometry/a.h:1", "a.cpp:1", "b.cpp:1", "c.cpp:2", "core/"]
        missed = [w for w in want if not any(w in b for b in found)]
        if missed or len(found) != len(want):
            sys.exit("check_module_rule: the checker itself is wrong: missed %s, found %s" % (missed, found))


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    self_test()
    bad = check(sys.argv[1])
    for b in bad:
        print(b)
    if bad:
        print("%d violation(s) of the module rule" % len(bad))
        return 1
    print("module rule holds: %s" % ", ".join(MODULES))
    return 0


if __name__ == "__main__":
    sys.exit(main())
