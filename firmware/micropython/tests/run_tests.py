# MicroPython test runner: the anchor core's unit tests and every golden vector in
# protocol/vectors/*.json. Run from anywhere with the unix port:
#   micropython firmware/micropython/tests/run_tests.py [-v] [name-substring]
# Prints "N passed, N failed" last and exits 1 on any failure.
import sys


def _dirname(p):
    i = p.rfind("/")
    return p[:i] if i >= 0 else "."


_HERE = _dirname(__file__)
_MPY = _HERE + "/.."  # firmware/micropython
ROOT = _MPY + "/../../"  # repository root, for protocol/
sys.path.insert(0, _MPY)
sys.path.insert(0, _HERE)

_MODULES = ("test_wire", "test_anchor", "test_glue", "test_vectors")


def _run(name, fn, verbose, tally):
    try:
        fn()
    except Exception as e:  # noqa: BLE001 - report every failure and carry on
        tally[1] += 1
        print("FAIL", name)
        sys.print_exception(e)
        return
    tally[0] += 1
    if verbose:
        print("ok  ", name)


def main(argv):
    verbose = "-v" in argv
    pattern = [a for a in argv if not a.startswith("-")]
    tally = [0, 0]
    for modname in _MODULES:
        try:
            mod = __import__(modname)
            cases = getattr(mod, "cases", None)
            items = cases() if cases else [
                (k, getattr(mod, k)) for k in sorted(dir(mod)) if k.startswith("test_")]
        except Exception as e:  # noqa: BLE001 - a module that cannot load is a failure
            tally[1] += 1
            print("FAIL", modname, "(loading)")
            sys.print_exception(e)
            continue
        for k, fn in items:
            name = modname + "." + k
            if pattern and not any(p in name for p in pattern):
                continue
            _run(name, fn, verbose, tally)
    print("%d passed, %d failed" % (tally[0], tally[1]))
    return 1 if tally[1] or not tally[0] else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
