/*
 * anchor_script - runs an event script (protocol/vectors/README.md) read from stdin
 * through one C anchor and prints every frame it emits, one line each, as the reference
 * runner pfdoa.protocol.script.run_script does:
 *     U <hex of the UART frame incl. its 00 delimiter>
 *     C <3-hex-digit id> <hex data>
 * Usage: anchor_script [-a anchor_id] [-t uart|can|both] [-b boot_tick_ms]
 *                      [-c offset_q8,alpha_q8,spike_db,report_mode,decimation] [-s]
 *   -a  anchor id 0..126 (default 1)
 *   -t  transports (default uart)
 *   -b  tick at initialisation (default 0)
 *   -c  configuration found in storage at boot (default: none, so the SPEC defaults)
 *   -s  the configuration store fails (CONFIG_ACK result 2)
 * Batch mode (many sequences in one process): a line `@ <json init>` (a vector's `init`
 * object: anchor_id, transport uart|can|both, boot_tick_ms, fw_major, fw_minor, config,
 * filters, store_ok, sil_inject) starts a fresh anchor and prints `@` before its frames. fw must be
 * PFDOA_FW_MAJOR.MINOR and sil_inject must match the build (anchor_script_sil for true).
 * Exit status: 0; 2 with "line N: ..." on stderr for a malformed script or bad option.
 * anchor_script_sil is the same with PFDOA_SIL_INJECT (RADIO_INJECT frames accepted).
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "script.h"

static void print_line(void *const user, const char *const line)
{
    (void)user;
    (void)puts(line);
}

static int usage(void)
{
    (void)fputs("usage: anchor_script [-a anchor_id] [-t uart|can|both] [-b boot_tick_ms]\n"
                "                     [-c offset_q8,alpha_q8,spike_db,report_mode,decimation] [-s] < script\n",
                stderr);
    return 2;
}

static int parse_ulong(const char *const s, const unsigned long max, unsigned long *const out)
{
    char *end = NULL;
    errno = 0;
    const unsigned long v = strtoul(s, &end, 10);
    if ((*s == '\0') || (*s == '-') || (errno != 0) || (*end != '\0') || (v > max)) {
        return -1;
    }
    *out = v;
    return 0;
}

int main(int argc, char **argv)
{
    script_env_t env;
    (void)memset(&env, 0, sizeof env);
    env.emit = print_line;
    unsigned long anchor_id = 1u;
    uint8_t transports = PFDOA_TRANSPORT_UART;
    for (int i = 1; i < argc; i++) {
        const char *const opt = argv[i];
        if (strcmp(opt, "-s") == 0) {
            env.store_fails = 1;
            continue;
        }
        if ((i + 1) >= argc) {
            return usage();
        }
        const char *const val = argv[++i];
        unsigned long v = 0u;
        if ((strcmp(opt, "-a") == 0) && (parse_ulong(val, PFDOA_ANCHOR_ID_MAX, &anchor_id) == 0)) {
            continue;
        }
        if ((strcmp(opt, "-b") == 0) && (parse_ulong(val, UINT32_MAX, &v) == 0)) {
            env.boot_tick = (uint32_t)v;
            continue;
        }
        if ((strcmp(opt, "-c") == 0) && (script_set_stored_config(&env, val) == 0)) {
            continue;
        }
        if (strcmp(opt, "-t") == 0) {
            if (strcmp(val, "uart") == 0) {
                transports = PFDOA_TRANSPORT_UART;
                continue;
            }
            if (strcmp(val, "can") == 0) {
                transports = PFDOA_TRANSPORT_CAN;
                continue;
            }
            if (strcmp(val, "both") == 0) {
                transports = PFDOA_TRANSPORT_UART | PFDOA_TRANSPORT_CAN;
                continue;
            }
        }
        return usage();
    }

    pfdoa_hal_t hal;
    script_hal(&env, &hal);
    pfdoa_filter_storage_t storage;
    script_filter_storage(&env, &storage);
    static pfdoa_anchor_t anchor;
    if ((pfdoa_anchor_init(&anchor, &hal, (uint8_t)anchor_id, transports) != PFDOA_OK) ||
        (pfdoa_anchor_use_filter_storage(&anchor, &storage) != PFDOA_OK)) {
        return usage();
    }
#ifdef PFDOA_SIL_INJECT
    const int sil_build = 1;
#else
    const int sil_build = 0;
#endif

    /* Lines up to 1 MiB: long enough for any UART chunk a test feeds. */
    enum { LINE_MAX_BYTES = 1 << 20 };
    static char line[LINE_MAX_BYTES];
    static uint8_t scratch[LINE_MAX_BYTES / 2];
    unsigned long lineno = 0u;
    while (fgets(line, sizeof line, stdin) != NULL) {
        lineno++;
        const size_t len = strlen(line);
        if ((len == (sizeof line - 1u)) && (line[len - 1u] != '\n')) {
            (void)fprintf(stderr, "line %lu: longer than %d bytes\n", lineno, LINE_MAX_BYTES - 2);
            return 2;
        }
        char shown[96];
        (void)snprintf(shown, sizeof shown, "%.80s", line);
        shown[strcspn(shown, "\r\n")] = '\0';
        if (line[0] == '@') {
            script_init_t in;
            char err[96];
            if (script_parse_init(&line[1], &in, err, sizeof err) != 0) {
                (void)fprintf(stderr, "line %lu: bad init: %s\n", lineno, err);
                return 2;
            }
            if ((in.fw_major != PFDOA_FW_MAJOR) || (in.fw_minor != PFDOA_FW_MINOR) || (in.sil_inject != sil_build)) {
                (void)fprintf(stderr, "line %lu: this harness is firmware %u.%u, %s PFDOA_SIL_INJECT\n", lineno,
                              PFDOA_FW_MAJOR, PFDOA_FW_MINOR, sil_build ? "with" : "without");
                return 2;
            }
            env.boot_tick = in.boot_tick;
            env.store_fails = !in.store_ok;
            env.have_stored = in.has_config;
            if (in.has_config != 0) {
                pfdoa_config_pack(&in.config, env.stored);
            }
            env.have_filters = in.has_filters;
            if (in.has_filters != 0) {
                (void)memcpy(env.filters, in.filters, sizeof env.filters);
            }
            pfdoa_peer_radio_t radio;
            script_peer_radio(&env, in.peer_radio, in.peer_address, &radio);
            if ((pfdoa_anchor_init(&anchor, &hal, in.anchor_id, in.transports) != PFDOA_OK) ||
                (pfdoa_anchor_use_filter_storage(&anchor, &storage) != PFDOA_OK) ||
                (pfdoa_anchor_use_peer_radio(&anchor, (in.has_peer_radio != 0) ? &radio : NULL) != PFDOA_OK)) {
                (void)fprintf(stderr, "line %lu: init failed\n", lineno);
                return 2;
            }
            (void)puts("@");
            continue;
        }
        if (script_run_line(&anchor, line, scratch, sizeof scratch) != 0) {
            (void)fflush(stdout);
            (void)fprintf(stderr, "line %lu: malformed: %s\n", lineno, shown);
            return 2;
        }
    }
    return (fflush(stdout) == 0) ? 0 : 1;
}
