"""Use cases: one module per use case, each taking a typed request and returning
a typed result (rig opening, calibrate, capture, relocate, diff, report, demo).

The CLI (`fgcd_cli.cli`) only parses options, builds the request, calls the use
case and renders its result; `demo` and `bench` call the same functions.
"""
