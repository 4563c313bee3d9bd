/*
 * dribble_messages.h: the messages the dribble controller exchanges over iceoryx2, for a
 * motion module (or camera driver, or simulator) written in C or C++.
 *
 * Every message is a plain struct without pointers, little-endian, with the same layout on
 * the Nao V5 (i686) and V6 (x86_64). Open the services with iceoryx2's C or C++ bindings
 * (publish-subscribe, no user header) under the service names and payload type names below;
 * iceoryx2 checks the type name, size and alignment when a port connects.
 *
 * The Rust definitions and layout tests are in controller/src/frame.rs,
 * controller/src/motion_command.rs and controller/src/transport/{lock_step,ipc}.rs.
 */
#ifndef DRIBBLE_MESSAGES_H
#define DRIBBLE_MESSAGES_H

#include <stddef.h>
#include <stdint.h>

/* Service names (iceoryx2 ServiceName). The command and tick services also exist as event
 * services of the same name: the publisher notifies after each message. */
#define DRIBBLE_TOP_CAMERA_SERVICE "dribble/camera/top"
#define DRIBBLE_BOTTOM_CAMERA_SERVICE "dribble/camera/bottom"
#define DRIBBLE_COMMAND_SERVICE "dribble/motion/command"
#define DRIBBLE_TICK_SERVICE "dribble/sim/tick"

/* Payload type names (iceoryx2 type_name). */
#define DRIBBLE_TOP_FRAME_TYPE "dribble::TopFrame"
#define DRIBBLE_BOTTOM_FRAME_TYPE "dribble::BottomFrame"
#define DRIBBLE_MOTION_COMMAND_TYPE "dribble::MotionCommand"
#define DRIBBLE_LOCK_STEP_TICK_TYPE "dribble::LockStepTick"

/* FourCC of packed YUV 4:2:2 (Y0 U Y1 V per pixel pair): 'Y' 'U' 'Y' 'V', little-endian. */
#define DRIBBLE_YUYV_FOURCC 0x56595559u

/* In front of every frame's pixels. */
typedef struct dribble_frame_header {
    uint64_t sequence;     /* counts up by one per frame of this camera */
    uint64_t timestamp_ns; /* exposure, CLOCK_MONOTONIC (simulated time in lock-step) */
    uint32_t width;
    uint32_t height;
    uint32_t format;   /* DRIBBLE_YUYV_FOURCC */
    uint32_t reserved; /* zero */
} dribble_frame_header;

/* Top camera, 640x480 YUYV: rows of 640 two-byte pixels, row-major. */
typedef struct dribble_top_frame {
    dribble_frame_header header;
    uint8_t pixels[480][640][2];
} dribble_top_frame;

/* Bottom camera, 320x240 YUYV. */
typedef struct dribble_bottom_frame {
    dribble_frame_header header;
    uint8_t pixels[240][320][2];
} dribble_bottom_frame;

/* Bits of dribble_motion_command.flags. */
#define DRIBBLE_COMMAND_NEW 1u      /* computed this tick from a new pair of frames */
#define DRIBBLE_COMMAND_REPEATED 2u /* the last command again: no new pair yet */
#define DRIBBLE_COMMAND_STOP 4u     /* stand still: no frames, a silent camera or simulator,
                                       a failed inference */
/* Frame sequence of a command computed from no frame. */
#define DRIBBLE_NO_FRAME UINT64_MAX

/* One command per controller tick (100 Hz). Speeds are normalised to [-1, 1] of the walk's
 * maximum: forward (+x, ahead), left (+y), turn (counter-clockwise). */
typedef struct dribble_motion_command {
    uint64_t sequence;        /* counts up by one per command */
    uint64_t timestamp_ns;    /* start of the tick that made it */
    uint64_t top_sequence;    /* frames it was computed from, or DRIBBLE_NO_FRAME */
    uint64_t bottom_sequence;
    float forward;
    float left;
    float turn;
    uint32_t flags; /* DRIBBLE_COMMAND_* */
} dribble_motion_command;

/* Lock-step simulation only: "run a tick now"; the answer is the command whose
 * timestamp_ns equals time_ns. Index 0, or a new episode, resets the controller. */
typedef struct dribble_lock_step_tick {
    uint64_t episode;
    uint64_t index;
    uint64_t time_ns;
} dribble_lock_step_tick;

#if defined(__cplusplus)
#define DRIBBLE_STATIC_ASSERT static_assert
#else
#define DRIBBLE_STATIC_ASSERT _Static_assert
#endif

DRIBBLE_STATIC_ASSERT(sizeof(dribble_frame_header) == 32, "frame header layout");
DRIBBLE_STATIC_ASSERT(offsetof(dribble_frame_header, width) == 16, "frame header layout");
DRIBBLE_STATIC_ASSERT(offsetof(dribble_frame_header, format) == 24, "frame header layout");
DRIBBLE_STATIC_ASSERT(sizeof(dribble_top_frame) == 614432, "top frame layout");
DRIBBLE_STATIC_ASSERT(sizeof(dribble_bottom_frame) == 153632, "bottom frame layout");
DRIBBLE_STATIC_ASSERT(sizeof(dribble_motion_command) == 48, "command layout");
DRIBBLE_STATIC_ASSERT(offsetof(dribble_motion_command, forward) == 32, "command layout");
DRIBBLE_STATIC_ASSERT(offsetof(dribble_motion_command, flags) == 44, "command layout");
DRIBBLE_STATIC_ASSERT(sizeof(dribble_lock_step_tick) == 24, "tick layout");

#endif /* DRIBBLE_MESSAGES_H */
