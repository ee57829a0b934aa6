//! Report of `ecsync tsn run`: summary.json, a text table, plots and report.html.
