"""Run one atheris target: ``python fuzz/py/run_atheris.py TARGET [libFuzzer options] [corpus dirs]``.

Only the project's modules are instrumented (``atheris.instrument_imports()`` around their
imports; ``instrument_all()`` would spend most of a short run instrumenting the stdlib).
"""

import importlib
import sys
from pathlib import Path

import atheris

sys.path.insert(0, str(Path(__file__).parent))

# What the harnesses reach, lazily too (the commands import most of it at run time): named
# here to be instrumented when first imported, not used (the harnesses use pfdoa.api).
INSTRUMENTED = (
    "pfdoa.cli", "pfdoa.commands.gateway", "pfdoa.commands.replay", "pfdoa.gateway.decoding",
    "pfdoa.gateway.inputs", "pfdoa.gateway.inputs.capture", "pfdoa.gateway.inputs.espresense",
    "pfdoa.gateway.localizer", "pfdoa.gateway.odomsource", "pfdoa.gateway.runner", "pfdoa.gateway.setup",
    "pfdoa.gateway.transports", "pfdoa.mqtt.inputs", "pfdoa.output", "pfdoa.protocol.can", "pfdoa.protocol.cobs",
    "pfdoa.protocol.uart", "pfdoa.readings.config", "pfdoa.readings.reassembly", "pfdoa.sinks.mcap", "pfdoa.site",
    "pfdoa.trace",
)

with atheris.instrument_imports(include=["pfdoa", "harnesses"]):
    for name in INSTRUMENTED:
        importlib.import_module(name)

    import harnesses


def main() -> None:
    target = harnesses.TARGETS[sys.argv[1]]
    atheris.Setup([sys.argv[0]] + sys.argv[2:], target)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
