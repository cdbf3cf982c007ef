# Batch runner for the differential test of the authenticated beacon (tests/firmware/test_auth_diff.py):
# reads "<key hex> <counter> <seq> <pan_id>" lines on stdin and prints, per line, what the
# MicroPython modules derive and build: rid adv_a ext_addr pad tag payload key_check
# adv_data pdu mpdu (hex, pad decimal), space separated. One process for thousands of lines.
#   micropython firmware/micropython/tests/auth_batch.py < inputs
import sys


def _dirname(p):
    i = p.rfind("/")
    return p[:i] if i >= 0 else "."


sys.path.insert(0, _dirname(__file__) + "/..")

import binascii  # noqa: E402
import pfdoa_auth as A  # noqa: E402
import pfdoa_beacon as B  # noqa: E402


def _h(b):
    return binascii.hexlify(bytes(b)).decode()


def main():
    out = sys.stdout
    for line in sys.stdin:
        f = line.split()
        if not f:
            continue
        key = binascii.unhexlify(f[0])
        counter, seq, pan = int(f[1]), int(f[2]), int(f[3])
        k = A.Key(key)
        ids = A.derive(k, counter)
        adv = B.auth_adv_data(k, ids, counter, seq)
        out.write(" ".join((_h(ids[0]), _h(ids[1]), _h(ids[2]), str(ids[3]), _h(A.tag(k, counter, seq)),
                            _h(A.payload(k, counter, seq, ids)), _h(A.key_check(key)), _h(adv),
                            _h(B.adv_pdu(ids[1], adv)), _h(B.auth_mpdu(k, ids, counter, seq, pan)))))
        out.write("\n")


main()
