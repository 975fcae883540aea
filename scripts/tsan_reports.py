#!/usr/bin/python3
"""ThreadSanitizer reports (the log_path files of scripts/sanitize.sh --thread) split into ours and
ROS': ROS' libraries (roscpp, nodelet, boost's, log4cxx) are not instrumented, so TSan cannot see
their atomic reference counts and reports races and lock-order cycles wholly inside them. A report
is ours when one of its accesses or locks is taken in this repository's code; a message freed by
ROS after its reference count dropped races with every earlier read of it, and counts only when
both sides are ours. Prints the number of ours (their text to stderr); writes the others, counted
by kind and first function, to OUTSIDE.
  tsan_reports.py REPORTS_DIR REPO_ROOT OUTSIDE"""
import collections
import glob
import re
import sys

if len(sys.argv) != 4:
    sys.exit(__doc__)
reports, repo, outside_file = sys.argv[1:]
ours, outside = [], collections.Counter()
for path in sorted(glob.glob(reports + "/*")):
    text = open(path, errors="replace").read()
    for block in text.split("==================")[1:]:
        head = re.search(r"WARNING: ThreadSanitizer: ([a-z -]+)", block)
        if not head:
            continue
        # Each stack's deciding frame: the first past the runtime and inlined headers (/usr/include):
        # a source line of this repository is ours; a library offset is ROS' (or its templates').
        kind, sides = head.group(1).strip(), []
        for stack in re.split(r"\n\s*\n", block):
            # (function, its source file if known, else its module)
            frames = [(m.group(1), m.group(2) or m.group(3)) for m in
                      re.finditer(r"#\d+ (\S+).*? (?:(\S+?):\d+(?::\d+)? )?\((\S+?)\+0x[0-9a-f]+\)$", stack, re.M)]
            if not frames:
                continue
            freed = re.search(r"#0 (operator delete|free)\b", stack) is not None
            decide = next(((fn, f) for fn, f in frames
                           if not re.search(r"libsanitizer|libtsan|^/usr/include/", f)), ("?", "?"))
            sides.append((decide[1].startswith(repo + "/") and not decide[1].startswith(repo + "/build/"), freed, decide[0]))
        # A message freed by roscpp after its (uninstrumented, so unseen) reference count dropped
        # races with every earlier read of it: not ours unless both sides are.
        mine = [m for m, _, _ in sides]
        if any(mine) and (kind != "data race" or all(mine) or not any(fr and not m for m, fr, _ in sides)):
            ours.append(block.strip())
        else:
            outside[(kind, next((fn for m, _, fn in sides if not m), "?")[:90])] += 1
with open(outside_file, "w") as f:
    for (kind, fn), n in outside.most_common():
        f.write("%5d %s in %s\n" % (n, kind, fn))
for b in ours[:5]:
    sys.stderr.write(b[:3000] + "\n==================\n")
print(len(ours))
