"""The HTML fleet report: one self-contained page, worst flights first.

Why this module exists: the table (Parquet, CSV) is for tools; a person
reviewing a day of flights wants to open one page, see which flights need a
look and why, and click through to each flight's own review page (written
by `cmsckf review --html`, next to this one under flights/). The page needs
no network and no script: inline CSS, one table, links.

"Worst" is an order anyone can check by hand, not a score: a flight whose
review failed, then a damaged log, then more filter resets, then more of our
positions the autopilot rejected, then a larger share of the flight spent
degraded, then a larger ATE against the truth.
"""

from __future__ import annotations

import datetime
import html


def _n(x) -> float:
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) else 0.0


def damaged(row: dict) -> bool:
    return row.get("log_finished") is False or bool(row.get("log_truncated")) or _n(row.get("chunks_dropped")) > 0


def badness(row: dict) -> tuple:
    """The sort key: larger is worse (see the module's note)."""
    duration = _n(row.get("duration_s")) or 1.0
    return (
        row.get("error") is not None,
        damaged(row),
        _n(row.get("resets")),
        _n(row.get("autopilot_rejected_reports")),
        _n(row.get("degraded_s")) / duration,
        _n(row.get("ate_m")),
    )


def why(row: dict) -> list[str]:
    """What is wrong with a flight, in words; empty for a clean one."""
    if row.get("error"):
        lines = row["error"].splitlines()
        first = next((l.strip() for l in lines if "Error" in l), lines[0] if lines else "")
        return ["review failed: " + first]
    out = []
    if damaged(row):
        out.append(
            "log damaged" + (f" ({int(_n(row['chunks_dropped']))} chunks dropped)" if _n(row.get("chunks_dropped")) else "")
        )
    if _n(row.get("resets")):
        n = int(_n(row["resets"]))
        out.append(f"{n} filter reset" + ("s" if n > 1 else ""))
    if _n(row.get("autopilot_rejected_reports")):
        out.append(
            f"autopilot rejected our position in {int(_n(row['autopilot_rejected_reports']))} of "
            f"{int(_n(row.get('autopilot_ratio_reports')))} reports"
        )
    if _n(row.get("degraded_s")):
        reasons = sorted(
            ((k[len("degraded_s_"):], v) for k, v in row.items() if k.startswith("degraded_s_") and _n(v)),
            key=lambda kv: -kv[1],
        )
        out.append(f"degraded {_n(row['degraded_s']):.0f} s (" + ", ".join(f"{k} {v:.0f} s" for k, v in reasons) + ")")
    return out


def _fmt(x, digits=3) -> str:
    if x is None:
        return "–"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float):
        return f"{x:.0f}" if abs(x) >= 100 else f"{x:.{digits}g}"
    return str(x)


def _pct(x) -> str:
    return "–" if x is None else f"{100 * x:.0f} %"


CSS = """
body{font:13px/1.4 system-ui,sans-serif;margin:1.5em;color:#222}
h1{font-size:1.4em;margin:0 0 .2em} .sub{color:#666;margin:0 0 1em}
.cards{display:flex;gap:1em;flex-wrap:wrap;margin-bottom:1.2em}
.card{border:1px solid #ddd;border-radius:6px;padding:.5em .9em;min-width:8em}
.card b{display:block;font-size:1.5em}
table{border-collapse:collapse;width:100%} th,td{padding:.3em .5em;border-bottom:1px solid #eee;text-align:right;white-space:nowrap}
th{background:#f4f4f4;position:sticky;top:0;white-space:normal;vertical-align:bottom} td.l,th.l{text-align:left;white-space:normal} td.why{min-width:18em} td.flight{white-space:nowrap}
tr.bad td.why{color:#b00020;font-weight:600} tr.ok td.why{color:#2e7d32}
td.hot{background:#fde7e9} pre{background:#f8f8f8;padding:.6em;overflow:auto;font-size:12px}
"""

# (heading, column, is it bad when non-zero); the shares are shown in %
SHARES = ("autopilot_acceptance", "ate_within_3sigma")
COLUMNS = [
    ("duration [s]", "duration_s", False),
    ("resets", "resets", True),
    ("degraded [s]", "degraded_s", True),
    ("autopilot accepted", "autopilot_acceptance", False),
    ("ATE [m]", "ate_m", False),
    ("ATE in ±3σ", "ate_within_3sigma", False),
    ("NIS/dof", "nis_per_dof_mean", False),
    ("µs/frame p99", "update_us_p99", False),
    ("rejected tracks", "rejected_total", False),
]


def write(rows: list[dict], path: str, title: str = "cmsckf fleet review") -> None:
    """Write the report for `rows` (already sorted worst first) to `path`."""
    e = html.escape
    flown = sum(_n(r.get("duration_s")) for r in rows)
    failed = [r for r in rows if r.get("error")]
    flagged = [r for r in rows if why(r) and not r.get("error")]
    replay = any("replay_differs" in r for r in rows)
    cards = [
        ("flights", len(rows)),
        ("flown", f"{flown / 3600:.2f} h" if flown >= 3600 else f"{flown:.0f} s"),
        ("need a look", len(flagged)),
        ("review failed", len(failed)),
        ("filter resets", int(sum(_n(r.get("resets")) for r in rows))),
        ("autopilot rejections", int(sum(_n(r.get("autopilot_rejected_reports")) for r in rows))),
    ]
    heads = "".join(f"<th>{e(h)}</th>" for h, _, _ in COLUMNS)
    if replay:
        heads += "<th>replay ATE [m]</th><th>replay vs flight [m]</th>"
    body = []
    for i, r in enumerate(rows, 1):
        reasons = why(r)
        link = (
            f'<a href="{e(r["review_page"])}">{e(r["flight"])}</a>' if r.get("review_page") else e(r["flight"])
        )
        cells = []
        for _, col, bad_when_nonzero in COLUMNS:
            hot = " class=hot" if bad_when_nonzero and _n(r.get(col)) else ""
            text = _pct(r.get(col)) if col in SHARES else _fmt(r.get(col))
            cells.append(f"<td{hot}>{text}</td>")
        if replay:
            cells.append(f"<td>{_fmt(r.get('replay_ate_m'))}</td><td>{_fmt(r.get('replay_max_position_diff_m'))}</td>")
        text = "; ".join(reasons) if reasons else "nothing to see"
        body.append(
            f'<tr class="{"bad" if reasons else "ok"}"><td>{i}</td><td class="l flight">{link}</td>'
            f'<td class="l why">{e(text)}</td>{"".join(cells)}</tr>'
        )
    failures = "".join(
        f"<h3>{e(r['flight'])}</h3><p>{e(r['log'])}</p><pre>{e(r['error'])}</pre>" for r in failed
    )
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{e(title)}</title>
<meta name="viewport" content="width=device-width, initial-scale=1"><style>{CSS}</style></head>
<body><h1>{e(title)}</h1>
<p class=sub>{len(rows)} flights, worst first: a failed review, a damaged log, filter resets, the autopilot
rejecting our position, time degraded, then ATE against the truth. Each flight links to its own review page.
Written {e(datetime.datetime.now().strftime("%Y-%m-%d %H:%M"))} by cmsckf-fleet review.</p>
<div class=cards>{"".join(f"<div class=card><b>{e(str(v))}</b>{e(k)}</div>" for k, v in cards)}</div>
<table><thead><tr><th>#</th><th class=l>flight</th><th class=l>what is wrong</th>{heads}</tr></thead>
<tbody>{"".join(body)}</tbody></table>
{"<h2>Reviews that failed</h2>" + failures if failed else ""}
</body></html>
"""
    with open(path, "w", encoding="utf-8") as f:
        f.write(page)
