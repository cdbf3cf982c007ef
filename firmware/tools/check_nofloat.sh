#!/usr/bin/env bash
# Fails if any of the given ELF/object files defines or references a floating-point
# helper (ARM EABI __aeabi_f*/__aeabi_d*/int<->float conversions, or libgcc's
# __addsf3-style soft-float routines).  Usage: check_nofloat.sh NM FILE...
set -euo pipefail
nm=$1; shift
pattern='(^|[[:space:]])(__aeabi_(f|d|u?[il]2[fd])[a-z0-9]*|__[a-z]*(sf|df|tf|xf)[a-z0-9]*)$'
status=0
for f in "$@"; do
  hits=$("$nm" "$f" | grep -E "$pattern" || true)
  if [ -n "$hits" ]; then
    echo "FAIL: floating-point helpers in $f:"; echo "$hits"; status=1
  fi
done
exit $status
