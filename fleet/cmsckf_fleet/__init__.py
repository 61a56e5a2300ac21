"""cmsckf-fleet: the `cmsckf` binary's own commands, run as Ray tasks.

Why this package exists: reviewing every flight of a fleet, sweeping
`cmsckf evaluate` over thousands of seeds and replaying a corpus under two
builds are each a loop on one machine. Here each iteration is one Ray task
that runs the Rust binary, so the same loop runs embedded on a laptop or on a
cluster, with the same answers. The estimator and the log tools stay in Rust:
nothing here computes a filter result of its own.

Modules: `cli` (the command line), `cluster` (Ray set-up, shipping the binary
and configs, streaming results), `binary` (running `cmsckf` and reporting its
failures), `sweep`, `review`, `regress` (the three commands), `estimates`
(comparing the estimates of two flight logs), `report` (the HTML fleet
report), `progress` (progress lines with an ETA).
"""

__version__ = "0.1.0"
