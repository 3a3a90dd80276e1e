/* Follows the outlet sidecar's hole poses from C: connects, waits for N
 * results and prints their holes.
 *
 *   cargo build --release -p outlet-client-c
 *   cc -std=c11 -Wall -Iclients/c/include clients/c/examples/follow.c \
 *      target/release/liboutlet_client_c.a -lpthread -ldl -lm -lrt -o follow
 *   ./follow [DOMAIN|-] [COUNT]      (DOMAIN "-" or absent: the default; COUNT default 10)
 */
#define _POSIX_C_SOURCE 200809L
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "outlet_client.h"

static uint64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

static void print_error(const char *what) {
    char text[512];
    outlet_last_error(text, sizeof text);
    fprintf(stderr, "follow: %s: %s\n", what, text);
}

int main(int argc, char **argv) {
    const char *domain = (argc > 1 && strcmp(argv[1], "-") != 0) ? argv[1] : NULL;
    long count = argc > 2 ? strtol(argv[2], NULL, 10) : 10;
    if (count <= 0) {
        fprintf(stderr, "usage: follow [DOMAIN|-] [COUNT > 0]\n");
        return 2;
    }

    OutletClient *client = outlet_client_connect(domain);
    if (client == NULL) {
        print_error("connecting");
        return 1;
    }
    printf("following hole poses in domain %s\n", domain ? domain : "(default)");
    fflush(stdout);

    int status = 0;
    long seen = 0;
    while (seen < count) {
        OutletHolePoses poses;
        int rc = outlet_client_wait_next(client, 1000, &poses);
        if (rc == OUTLET_NONE) {
            uint64_t last = outlet_client_last_result_ns(client);
            if (last == 0) {
                printf("no result yet\n");
            } else {
                printf("no result since %.1f s ago\n", (double)(now_ns() - last) / 1e9);
            }
            fflush(stdout);
            continue;
        }
        if (rc == OUTLET_ERR_INTERRUPTED) {
            break;
        }
        if (rc < 0) {
            print_error("waiting");
            status = 1;
            break;
        }
        seen++;
        double age_ms = (double)(now_ns() - poses.capture_time_ns) / 1e6;
        const char *mode = poses.mode == OUTLET_MODE_PLANE    ? "plane"
                           : poses.mode == OUTLET_MODE_NORMAL ? "normal"
                                                              : "mono";
        if (poses.status != OUTLET_STATUS_OK) {
            /* No pose this frame: ambiguous from pixels alone, or the stereo plane disagrees. */
            printf("frame %" PRIu64 " (%s): no pose (%s)\n", poses.frame_id, mode,
                   poses.status == OUTLET_STATUS_AMBIGUOUS ? "ambiguous" : "plane mismatch");
            fflush(stdout);
            continue;
        }
        printf("frame %" PRIu64 " (%s): %u holes, age %.1f ms\n", poses.frame_id, mode, poses.hole_count, age_ms);
        for (uint32_t k = 0; k < poses.hole_count && k < OUTLET_MAX_HOLES; k++) {
            const OutletHole *h = &poses.holes[k];
            printf("  %-6s %.6f %.6f %.6f m\n", h->kind == OUTLET_HOLE_GROUND ? "ground" : "power", h->position_m[0],
                   h->position_m[1], h->position_m[2]);
        }
        fflush(stdout);
    }
    if (outlet_client_rejected(client) > 0) {
        printf("%" PRIu64 " invalid messages rejected\n", outlet_client_rejected(client));
    }
    outlet_client_free(client);
    return status;
}
