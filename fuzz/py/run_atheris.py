"""Run one atheris target: ``python fuzz/py/run_atheris.py TARGET [libFuzzer options] [corpus dirs]``.

Only the project's modules are instrumented (``atheris.instrument_imports()`` around their
imports; ``instrument_all()`` would spend most of a short run instrumenting the stdlib).
"""

import sys
from pathlib import Path

import atheris

sys.path.insert(0, str(Path(__file__).parent))

with atheris.instrument_imports(include=["pfdoa", "harnesses"]):
    import pfdoa.cli  # noqa: F401
    import pfdoa.commands._common  # noqa: F401
    import pfdoa.commands.gateway  # noqa: F401
    import pfdoa.commands.replay  # noqa: F401
    import pfdoa.gateway.decoding  # noqa: F401
    import pfdoa.gateway.inputs  # noqa: F401
    import pfdoa.gateway.inputs.capture  # noqa: F401
    import pfdoa.gateway.inputs.espresense  # noqa: F401
    import pfdoa.gateway.localizer  # noqa: F401
    import pfdoa.gateway.odomsource  # noqa: F401
    import pfdoa.gateway.runner  # noqa: F401
    import pfdoa.gateway.setup  # noqa: F401
    import pfdoa.gateway.transports  # noqa: F401
    import pfdoa.mqtt.inputs  # noqa: F401
    import pfdoa.output  # noqa: F401
    import pfdoa.protocol.can  # noqa: F401
    import pfdoa.protocol.cobs  # noqa: F401
    import pfdoa.protocol.uart  # noqa: F401
    import pfdoa.readings.config  # noqa: F401
    import pfdoa.readings.reassembly  # noqa: F401
    import pfdoa.sinks.mcap  # noqa: F401
    import pfdoa.site  # noqa: F401
    import pfdoa.trace  # noqa: F401

    import harnesses


def main() -> None:
    target = harnesses.TARGETS[sys.argv[1]]
    atheris.Setup([sys.argv[0]] + sys.argv[2:], target)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
