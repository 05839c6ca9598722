"""The project's tools, not the library API: benchmarks (``python -m btfrs.tools.bench``), the
demo behind ``btfrs demo`` (:mod:`btfrs.tools.demo`), the Mitsuba ground-truth check
(:mod:`btfrs.tools.groundtruth`, the ``groundtruth`` extra) and the memory probe the out-of-core
tests run in a fresh interpreter (``python -m btfrs.tools.memprobe``).

They import the library; the library never imports them (``import btfrs`` loads none of them, and
``tests/test_layering.py`` checks both). Their options, output and functions may change with the
benchmarks and checks they serve.
"""
