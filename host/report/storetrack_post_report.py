#!/usr/bin/env python3
"""storetrack-post's truth-free report: HTML page + PNG plots of a storetrack-post --report
directory (docs/post-processing.md): real-time beside smoothed trajectory and attitude with k = 2
bands, velocities and body rates, per-camera residual diagnostics, rigid-body fit chi-square,
camera usage and gaps, the recording's integrity. The main job's report (storetrack_report.py
--post) is the same code with the simulator's truth added.

Usage: storetrack_post_report.py DIR [--out OUTDIR]   (default OUTDIR: DIR; index.html there)
"""
import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from post_report import load_post_dir, render_post  # noqa: E402
from report_html import table, write_page  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir", help="storetrack-post --report directory")
    ap.add_argument("--out", help="where index.html and the PNGs go (default: DIR)")
    args = ap.parse_args()
    out = args.out or args.dir
    if os.path.exists(os.path.join(out, "index.html")):
        print("report: %s: exists; the report writes new files only" %
              os.path.join(out, "index.html"), file=sys.stderr)
        return 2
    post = load_post_dir(args.dir)
    if post["samples"] is None or len(post["samples"].get("trigger_seq", [])) == 0:
        print("report: %s: no samples" % args.dir, file=sys.stderr)
        return 2
    os.makedirs(out, exist_ok=True)
    figures, summary = [], []
    render_post(post, out, figures, summary, post["samples"]["exposure_mid_tai_ns"][0])
    body = ("<h1>storetrack-post report: %s</h1><p>No truth: every check here is the data's own "
            "consistency with its stated uncertainty. Bands are k = 2 expanded uncertainties.</p>"
            % os.path.abspath(args.dir))
    body += "<h2>Summary</h2>" + table(["quantity", "value"], summary)
    for name in figures:
        body += "<h2>%s</h2><img src='%s' style='max-width:100%%'>" % (name[:-4].replace("_", " "),
                                                                         name)
    for k, v in summary:
        print("%-90s %s" % (k, v))
    write_page(out, body, title="storetrack-post report")
    return 0


if __name__ == "__main__":
    sys.exit(main())
