/*
 * hood.h: the C ABI of hood (HOOD-style neural cloth). C99; usable from C++ unchanged.
 *
 * Link with the static library (libhood_ffi.a; on Linux also -lpthread -ldl -lm) or the dynamic
 * library (libhood_ffi.so / .dylib / .dll; on Windows define HOOD_SHARED when using the DLL).
 *
 * Conventions
 * -----------
 * - Units: metres; y is up; one step is one frame at the model's 30 Hz (velocities are metres per
 *   frame). Positions are arrays of 3 * n floats (x, y, z per vertex); counts passed beside
 *   arrays are VERTEX (or face) counts, never float counts, and are checked against the handle.
 * - Every function except hood_version, hood_version_string, hood_last_error, hood_status_string
 *   and hood_sim_config_default returns a hood_status: HOOD_OK (0) or an error code below. After
 *   an error, hood_last_error() explains it (hood_status_string names the code). Out-parameters
 *   are written only on success. A failed call changes nothing (a refused step leaves the
 *   simulation state unchanged).
 * - Structs the caller passes in (hood_sim_config, hood_body_desc, hood_executor, hood_material)
 *   start with `uint32_t struct_size`: set it to sizeof(the struct) (hood_sim_config_default
 *   sets it for the config). It lets the structs grow in later versions without a caller built
 *   against another header being misread. Every call that reads such a struct checks it and
 *   reads a smaller struct_size (an older header, down to the struct's size in version 0.2.0)
 *   with the fields added since as zero, and refuses, with HOOD_ERR_STRUCT_SIZE: a struct_size
 *   smaller than that; one larger than 4096 or not a multiple of the struct's alignment; and a
 *   larger one (a newer header) unless every byte past the library's sizeof, up to struct_size,
 *   is zero. Every field a later version adds takes zero to mean "unset", so an older caller
 *   runs on a newer library, and a newer caller on an older library as long as it leaves the
 *   new fields zero: zero the whole struct (memset) before filling it. In an array of hood_material, materials[0].struct_size is the element
 *   size (stride) and every element must carry the same struct_size.
 * - Structs the library fills in (hood_model_info, hood_refinement, hood_body_survey) also start
 *   with `uint32_t struct_size`, which the caller sets to sizeof(the struct) before the call. The
 *   library checks it as above (HOOD_ERR_STRUCT_SIZE, nothing written) and writes exactly
 *   struct_size bytes: the fields it knows, then zeros (so fields of a newer header read 0).
 * - NULL handles or pointers give HOOD_ERR_NULL_POINTER, never a crash; where a pointer is
 *   optional, the comment says so. Handles that were never created or were already freed give
 *   HOOD_ERR_INVALID_HANDLE (the library keeps a registry of live models and garments, and sims
 *   in memory it never frees; an address reused by a newer handle of the same kind cannot be
 *   told apart from it, and a freed sim's address is reused only after 4096 other sims have been
 *   freed). Free functions accept NULL.
 * - No panic crosses the boundary: an internal bug is reported as HOOD_ERR_PANIC.
 *
 * Ownership and lifetimes (the caller's responsibility)
 * ---------------------------------------------------
 * - hood_model_load does NOT copy the model bytes: they must start at a HOOD_MODEL_ALIGN-byte
 *   aligned address, stay valid and unmodified until hood_model_free has returned HOOD_OK, and
 *   hence outlive every sim created from the model.
 * - A model cannot be freed while sims made from it live: hood_model_free then returns
 *   HOOD_ERR_MODEL_IN_USE and frees nothing. A garment may be freed right after hood_sim_new
 *   (the sim keeps its own copy).
 * - Pointers into caller arrays are only read during the call. Arrays must be aligned for their
 *   element type (float, uint32_t: 4 bytes), and an output array must not overlap an input of the
 *   same call: both give HOOD_ERR_BAD_POINTER.
 *
 * Threads
 * -------
 * - A model may be shared by sims on many threads (it is read-only after loading).
 * - One sim is used by one thread at a time; different sims may be stepped concurrently. The
 *   library enforces it: a call on a sim that another thread is stepping or changing (or a
 *   hood_sim_free while it does) returns HOOD_ERR_BUSY and does nothing; calls that only read a
 *   sim may overlap each other. Calls on a sim (hood_sim_step above all) take no lock: the check
 *   is one atomic operation on the sim's own state, so sims on different threads never wait for
 *   each other. Only hood_sim_new and hood_sim_free take a global lock, briefly.
 * - A model or garment is read by calls on it, and by hood_sim_new, only while the call runs; a
 *   hood_model_free or hood_garment_free meanwhile (from another thread, or from the log callback
 *   during that call) returns HOOD_ERR_BUSY and frees nothing.
 * - hood_last_error() is per thread.
 * - Callbacks (the executor's run, the log callback) must not throw a C++ exception or otherwise
 *   unwind into the library: that aborts the process. Catch inside the callback.
 *
 * Linkage and calling convention
 * ------------------------------
 * - HOOD_API marks every function declaration: on Windows __declspec(dllimport) when HOOD_SHARED
 *   is defined (linking hood_ffi.dll through its import library), else nothing (the static
 *   library); elsewhere, with GCC or Clang, default symbol visibility (so that a
 *   `#pragma GCC visibility push(hidden)` around the include does not hide them). Define HOOD_API
 *   before including this header to override it.
 * - HOOD_CALL is the calling convention of every function and callback type: __cdecl on 32-bit
 *   Windows (the library's, whatever default the caller's compiler uses, e.g. /Gz or /Gr), empty
 *   elsewhere. A callback the caller passes in (hood_executor.run) must be declared with it.
 */
#ifndef HOOD_H
#define HOOD_H

#include <stddef.h>
#include <stdint.h>

#ifndef HOOD_API
#if defined(_WIN32)
#if defined(HOOD_SHARED)
#define HOOD_API __declspec(dllimport)
#else
#define HOOD_API
#endif
#elif defined(__GNUC__) || defined(__clang__)
#define HOOD_API __attribute__((visibility("default")))
#else
#define HOOD_API
#endif
#endif

#if defined(_WIN32) && !defined(_WIN64)
#define HOOD_CALL __cdecl
#else
#define HOOD_CALL
#endif

#ifdef __cplusplus
extern "C" {
#endif

/* ---- Version ----------------------------------------------------------------------------- */

#define HOOD_VERSION_MAJOR 0
#define HOOD_VERSION_MINOR 3
#define HOOD_VERSION_PATCH 0
/* The version as one number: (major << 16) | (minor << 8) | patch. */
#define HOOD_MAKE_VERSION(major, minor, patch) (((uint32_t)(major) << 16) | ((uint32_t)(minor) << 8) | (uint32_t)(patch))
#define HOOD_VERSION HOOD_MAKE_VERSION(HOOD_VERSION_MAJOR, HOOD_VERSION_MINOR, HOOD_VERSION_PATCH)

/* The library's version, as HOOD_MAKE_VERSION encodes it (compare with HOOD_VERSION). */
HOOD_API uint32_t HOOD_CALL hood_version(void);
/* The library's version as "major.minor.patch" (static storage, NUL-terminated). */
HOOD_API const char *HOOD_CALL hood_version_string(void);

/* ---- Status codes (never reused) --------------------------------------------------------- */

typedef uint32_t hood_status;

#define HOOD_OK 0u                     /* success */
/* Codes 1-15 mirror hood::Error (Error::code). */
#define HOOD_ERR_INDEX_OUT_OF_RANGE 1u /* an index (e.g. in a face) refers past the end */
#define HOOD_ERR_NON_FINITE 2u         /* a coordinate or parameter is NaN or infinite */
#define HOOD_ERR_DEGENERATE_FACE 3u    /* a garment triangle has zero area */
#define HOOD_ERR_REPEATED_VERTEX 4u    /* a triangle names the same vertex twice */
#define HOOD_ERR_UNUSED_VERTEX 5u      /* a garment vertex belongs to no triangle */
#define HOOD_ERR_EMPTY 6u              /* something that must not be empty is */
#define HOOD_ERR_SIZE_MISMATCH 7u      /* an array has the wrong length */
#define HOOD_ERR_OUT_OF_RANGE 8u       /* a value is outside its documented range */
#define HOOD_ERR_CAPACITY_EXCEEDED 9u  /* a capacity fixed at creation, or a bound such as HOOD_MAX_VERTICES, was exceeded */
#define HOOD_ERR_INCOMPATIBLE_MODEL 10u /* the model cannot run this garment/body/config */
#define HOOD_ERR_UNSUPPORTED_EFFECT 11u /* an effect the model, the configuration or this build does not support */
#define HOOD_ERR_CORRUPT_DATA 12u      /* model bytes corrupt, truncated, misaligned, other version */
#define HOOD_ERR_PARSE 13u             /* a text input could not be parsed */
#define HOOD_ERR_IO 14u                /* an operating-system I/O failure */
#define HOOD_ERR_INSIDE_OUT 15u        /* the body mesh is wound inside out (reverse every face) */
/* Codes of the C ABI itself. */
#define HOOD_ERR_NULL_POINTER 100u     /* a required pointer argument is NULL */
#define HOOD_ERR_INVALID_HANDLE 101u   /* not a live handle of that kind (freed, or never made) */
#define HOOD_ERR_MODEL_IN_USE 102u     /* hood_model_free on a model that live sims still use */
#define HOOD_ERR_PANIC 103u            /* an internal error (a bug in hood); the handle may be unusable */
#define HOOD_ERR_BAD_POINTER 104u      /* a pointer misaligned for its type, or an output overlapping an input */
#define HOOD_ERR_BUSY 105u             /* the handle is in use by another call: a sim on another thread, or a model or garment being read */
#define HOOD_ERR_STRUCT_SIZE 106u      /* struct_size is not one this library knows: the caller was built against another header */
#define HOOD_ERR_TOO_LATE 107u         /* hood_set_allocator after the library has allocated (call it first) */

/* The message of the most recent failing call on this thread ("" if none): NUL-terminated, owned
 * by the library, valid until the next hood_* call on this thread. Successful calls leave it. */
HOOD_API const char *HOOD_CALL hood_last_error(void);
/* The name and meaning of a status code, e.g. "HOOD_ERR_NULL_POINTER: a required pointer argument
 * is NULL"; "unknown status" for a code this library does not have. NUL-terminated, static
 * storage; never fails and leaves hood_last_error alone. */
HOOD_API const char *HOOD_CALL hood_status_string(hood_status code);

/* ---- Allocator ------------------------------------------------------------------------------ */

/* An engine's allocator. `alloc(size, align, user)` returns `size` bytes aligned to `align` (a
 * power of two; size > 0), or NULL when out of memory (the library then aborts, as Rust does on
 * allocation failure). `free(ptr, size, align, user)` releases a block `alloc` returned, with the
 * same size and alignment. Both may be called from any thread, concurrently, and must not call
 * hood_* functions or throw. */
typedef struct hood_allocator {
    uint32_t struct_size; /* sizeof(hood_allocator) (see Conventions) */
    void *user;
    void *(HOOD_CALL *alloc)(size_t size, size_t align, void *user);
    void (HOOD_CALL *free)(void *ptr, size_t size, size_t align, void *user);
} hood_allocator;

/* Routes every allocation of the library to `allocator` (copied), for the life of the process.
 * It must come before any other hood_* call (every call may allocate; blocks must go back to the
 * allocator that gave them): afterwards, and after a refused call, it returns HOOD_ERR_TOO_LATE
 * and changes nothing. Without it the library uses the system allocator (malloc). */
HOOD_API hood_status HOOD_CALL hood_set_allocator(const hood_allocator *allocator);

/* ---- Log ------------------------------------------------------------------------------------ */

#define HOOD_LOG_ERROR 1u   /* an internal error: the message of a panic caught at the boundary */
#define HOOD_LOG_WARNING 2u /* a warning, e.g. a body mesh too coarse for its collisions */

/* Receives a message: `level` (HOOD_LOG_*), `message` (NUL-terminated UTF-8, valid only during
 * the call), `user` as given to hood_set_log_callback. Called on the thread whose hood_* call
 * (or executor task) produced the message, so possibly on several threads at once; it may call
 * hood_* functions, and must not throw (see Threads). */
typedef void (HOOD_CALL *hood_log_fn)(uint32_t level, const char *message, void *user);

/* Sets the process-wide log callback (NULL removes it). With one set, the library's warnings
 * (today: hood_sim_new with a body too coarse for the 3 cm body-edge radius, see
 * hood_body_survey) and the message of every internal error caught at the boundary (the call
 * returns HOOD_ERR_PANIC; the same text is its hood_last_error) go to it, and internal errors
 * no longer print to stderr. Without one, warnings go nowhere and an internal error prints
 * Rust's panic message to stderr. A call already running on another thread may still use the
 * previous callback after this returns: keep its `user` valid until such calls are done. Any
 * time, any thread. */
HOOD_API hood_status HOOD_CALL hood_set_log_callback(hood_log_fn callback, void *user);

/* ---- Model ------------------------------------------------------------------------------- */

/* Required alignment (bytes) of the model buffer given to hood_model_load. A buffer aligned to
 * 64 bytes starts every weight array of the file on a cache line, which the kernels read
 * fastest. */
#define HOOD_MODEL_ALIGN 16
/* Most bytes of a model buffer, and of the weights (f32 and bf16) its spec needs: a bigger one
 * gives HOOD_ERR_CAPACITY_EXCEEDED before any layer is read. */
#define HOOD_MAX_MODEL_BYTES 1073741824

typedef struct hood_model hood_model;

/* Validates a .hood model file held in memory and views its weights in place (no copy).
 * `bytes` must be HOOD_MODEL_ALIGN-aligned (else HOOD_ERR_CORRUPT_DATA) and must stay valid and
 * unmodified until hood_model_free(*out) returns HOOD_OK. */
HOOD_API hood_status HOOD_CALL hood_model_load(const uint8_t *bytes, size_t len, hood_model **out);
/* Frees a model (NULL: nothing to do). HOOD_ERR_MODEL_IN_USE while sims made from it live;
 * HOOD_ERR_BUSY, freeing nothing, while another call reads it (see Threads). */
HOOD_API hood_status HOOD_CALL hood_model_free(hood_model *model);
/* Whether the model file holds bf16 weights too (needed for HOOD_PRECISION_BF16): 1 or 0. */
HOOD_API hood_status HOOD_CALL hood_model_has_bf16(const hood_model *model, uint32_t *out);

/* What a model is. Set struct_size = sizeof(hood_model_info) before hood_model_get_info (see
 * Conventions). */
typedef struct hood_model_info {
    uint32_t struct_size;     /* sizeof(hood_model_info), set by the caller */
    uint32_t format_version;  /* .hood format version of the file (1: no checksum, 2: CRC-32) */
    uint32_t latent;          /* latent width h */
    uint32_t hidden_layers;   /* hidden layers per MLP */
    uint32_t blocks;          /* processor blocks (their edge sets: HOOD_MODEL_TEXT_SCHEDULE) */
    uint32_t levels;          /* coarse levels of the garment hierarchy */
    uint32_t has_bf16;        /* 1: bf16 weights present (HOOD_PRECISION_BF16 runs), else 0 */
    uint32_t effects;         /* trained with: HOOD_EFFECT_BODY_COLLISION, HOOD_EFFECT_PINNING */
    uint32_t local_materials; /* 1: trained with per-vertex materials, else one per garment */
    float frame_time;         /* seconds one step advances (1/30: the model runs at 30 Hz) */
    float length_unit;        /* metres per unit of every position (1) */
    uint32_t up_axis;         /* 0 x, 1 y, 2 z: the axis gravity points against (1) */
    size_t parameters;        /* learned parameters */
    size_t schedule_len;      /* bytes of the HOOD_MODEL_TEXT_SCHEDULE text, without the NUL */
    size_t provenance_len;    /* bytes of the HOOD_MODEL_TEXT_PROVENANCE text, without the NUL */
} hood_model_info;
HOOD_API hood_status HOOD_CALL hood_model_get_info(const hood_model *model, hood_model_info *out);

/* Texts of a model for hood_model_text. */
#define HOOD_MODEL_TEXT_SCHEDULE 0u   /* the processor blocks' edge sets, e.g. "0,1,2|m|..." */
#define HOOD_MODEL_TEXT_PROVENANCE 1u /* "key: value" lines (training config, data, iterations,
                                         metrics, commit), each ending in a newline */
/* Copies a model's text (`which`: HOOD_MODEL_TEXT_*, else HOOD_ERR_OUT_OF_RANGE) into `out`,
 * NUL-terminated: `len` must exceed the text's length from hood_model_get_info (else
 * HOOD_ERR_SIZE_MISMATCH, nothing written). */
HOOD_API hood_status HOOD_CALL hood_model_text(const hood_model *model, uint32_t which, char *out, size_t len);

/* ---- Garment ----------------------------------------------------------------------------- */

/* Material of a cloth vertex, SI units (training ranges in hood::mesh::material::ranges). */
typedef struct hood_material {
    uint32_t struct_size; /* sizeof(hood_material); in an array, every element's (see Conventions) */
    float density; /* area density, kg/m^2 */
    float mu;      /* Lame mu, Pa */
    float lambda;  /* Lame lambda, Pa */
    float bending; /* bending stiffness, J */
} hood_material;

typedef struct hood_garment hood_garment;

/* Most vertices, and most triangles, of a garment or a body: larger counts give
 * HOOD_ERR_CAPACITY_EXCEEDED before any array is read. */
#define HOOD_MAX_VERTICES 16777216
#define HOOD_MAX_FACES 33554432

/* A garment mesh. `rest`: 3 * n_vertices floats (metres); `indices`: 3 * n_faces vertex
 * indices, counter-clockwise seen from outside. `materials` (optional, NULL with n_materials 0
 * for the default material): 1 (for all) or n_vertices entries, each materials[0].struct_size
 * bytes. `pinned` (optional, NULL for none): n_vertices flags, nonzero = pinned. */
HOOD_API hood_status HOOD_CALL hood_garment_new(const float *rest, size_t n_vertices, const uint32_t *indices,
                                                size_t n_faces, const hood_material *materials, size_t n_materials,
                                                const uint8_t *pinned, hood_garment **out);
/* Frees a garment (NULL: nothing to do); HOOD_ERR_BUSY, freeing nothing, while another call reads
 * it (see Threads). */
HOOD_API hood_status HOOD_CALL hood_garment_free(hood_garment *garment);
HOOD_API hood_status HOOD_CALL hood_garment_vertex_count(const hood_garment *garment, size_t *out);
HOOD_API hood_status HOOD_CALL hood_garment_face_count(const hood_garment *garment, size_t *out);

/* ---- Simulation -------------------------------------------------------------------------- */

/* Effect flags of hood_sim_config.effects. What is off costs nothing. */
#define HOOD_EFFECT_BODY_COLLISION 1u /* body nodes and edges (needs a body in hood_sim_new) */
#define HOOD_EFFECT_PINNING 2u        /* drive pinned vertices to their targets */
#define HOOD_EFFECT_NORMALS 4u        /* compute vertex normals after each step (hood_sim_normals) */
#define HOOD_EFFECT_SLEEPING 8u       /* skip steps while body and garment are at rest */
#define HOOD_EFFECT_STARTUP 16u       /* relaxation step with a static body before the first step */
#define HOOD_EFFECT_AUTO_TELEPORT 32u /* body jumps beyond teleport_threshold carry the garment along */
#define HOOD_EFFECT_SPEED_LIMIT 64u   /* body speeds beyond speed_limit carry the garment along */
#define HOOD_EFFECT_COLLISION_PROJECTION 128u /* push cloth that ends up in the body out of it */
#define HOOD_EFFECT_REFINE 256u /* refine each step toward the physics optimum (refine_iterations) */
#define HOOD_EFFECT_TETHER 512u /* keep worn cloth near where it was put on the body (tether_slack) */

#define HOOD_PRECISION_F32 0u  /* f32 weights and activations */
#define HOOD_PRECISION_BF16 1u /* bf16 weights past the encoders, f32 accumulation (model with bf16 weights) */

typedef struct hood_sim_config {
    uint32_t struct_size;    /* sizeof(hood_sim_config) (see Conventions); hood_sim_config_default sets it */
    uint32_t effects;        /* HOOD_EFFECT_* flags */
    uint32_t precision;      /* HOOD_PRECISION_* */
    uint32_t threads;        /* threads without an executor (0 or 1: the calling thread; at most 256,
                                else HOOD_ERR_OUT_OF_RANGE; capped at the machine's cores, with a
                                HOOD_LOG_WARNING; fewer if the system refuses some) */
    uint32_t sleep_frames;   /* frames at rest before sleeping (HOOD_EFFECT_SLEEPING) */
    float sleep_threshold;   /* "at rest": body motion and garment speed below this, m/frame */
    float teleport_threshold; /* HOOD_EFFECT_AUTO_TELEPORT: when the body's centroid, or some body
                                 vertex beyond what the speed limit carries, moves farther than this
                                 (m) in one frame, hood_sim_step moves the garment by the body's
                                 best-fit rigid motion instead of simulating the jump */
    float speed_limit;       /* HOOD_EFFECT_SPEED_LIMIT: when the body's centroid moves farther than
                                this (m) in one frame, the step runs in a frame of reference that
                                follows the excess: the garment is carried by it and the network
                                sees the body move this far (like the inertia scales of game cloth) */
    float projection_margin; /* HOOD_EFFECT_COLLISION_PROJECTION: after every step, each free garment
                                vertex closer than this (m; 0 <= margin < 0.05) to the plane of its
                                nearest body face (by centroid, within 0.05 m), or behind it, moves
                                along the face normal to the margin, velocity included. A
                                post-process outside HOOD: one nearest-face search per step */
    uint32_t refine_iterations; /* HOOD_EFFECT_REFINE: every network step is refined by this many
                                   (1 ..= 1000) L-BFGS iterations of the physics objective (f32,
                                   training form), started from the network's prediction. Trades
                                   time for accuracy; the cost grows with the garment's vertices */
    uint32_t solver_iterations; /* N (1 ..= 1000; hood_sim_config_default: 30): the solver step
                                   mode, no network: each step is the implicit step of the same
                                   objective by N L-BFGS iterations from the coasting guess, with
                                   no start-up step (HOOD_EFFECT_REFINE must be off, else
                                   HOOD_ERR_UNSUPPORTED_EFFECT). hood_sim_last_refinement reports
                                   each solve. 0: the network computes every step (HOOD). The
                                   default is the accuracy/time map's pick: 30 iterations are
                                   at least as accurate as both shipped networks, in less time,
                                   on the walk, the run and every material measured (not the
                                   jump: docs/performance.md) */
    uint32_t solver_budget_us;  /* (since 0.3.0) 0: no time budget. B > 0, with solver_iterations
                                   N: each step's solve also starts no iteration that it predicts
                                   would end past B microseconds (at least one runs), so it takes
                                   at most N iterations and about B us: the step that fits a frame's
                                   budget, its result no longer reproducible bit for bit. Without
                                   solver_iterations: HOOD_ERR_UNSUPPORTED_EFFECT */
    float tether_slack;         /* (since 0.3.0) HOOD_EFFECT_TETHER: at the first step (and the first
                                   after hood_sim_reset), every free garment vertex within 0.1 m of
                                   a body vertex is tied to the nearest one; after every step a
                                   vertex farther from it than its distance then plus this slack
                                   (m; 0 <= slack <= 1) moves straight back to that length, and
                                   the cloth around it follows (no edge from a moved vertex kept
                                   over 1.5 times its rest length), velocity included. The "max
                                   distance" of game cloth, outside
                                   HOOD and the physics: for garments that must stay on whatever
                                   the motion (a top upside down). Applied after the collision
                                   projection when both are on, the cloth then following the
                                   projection's moves too. Needs a body.
                                   hood_sim_load_state and hood_sim_teleport keep the ties. A
                                   struct_size that ends before this field (an older header)
                                   reads as the default 0.05 m, not 0 */
} hood_sim_config;

/* The defaults into a caller's config: hood_sim_config_init(&cfg, sizeof cfg) writes exactly
 * struct_size bytes (the fields this library knows, zeros after them) and sets struct_size. The
 * defaults: body collision, pinning, start-up, auto-teleport (0.45 m) and the speed limit
 * (0.12 m/frame, 3.6 m/s) on; collision projection off (margin 0.002 m); tethers off
 * (slack 0.05 m); refinement off (10 iterations); the solver step mode at 30 iterations; f32;
 * 1 thread; sleeping after 3 frames below 1e-5 m/frame (when enabled). A struct_size the library
 * cannot serve (smaller than the struct of version 0.2.0, over 4096, or misaligned) gives
 * HOOD_ERR_STRUCT_SIZE and writes nothing. */
HOOD_API hood_status HOOD_CALL hood_sim_config_init(hood_sim_config *out, size_t struct_size);
/* hood_sim_config_init(out, sizeof *out): through this header the name is a macro, which also
 * works after C++'s `::` and gives that call's status (a plain call may ignore it). The exported
 * function of that name (what a program built against version 0.2.0 calls, or a binding that
 * loads symbols) cannot know its caller's size: it writes the defaults of the fields of version
 * 0.2.0 (through solver_iterations) and sets struct_size to that size, so the fields added since
 * read as unset. A NULL `out` is ignored (only hood_last_error records it). */
HOOD_API void HOOD_CALL hood_sim_config_default(hood_sim_config *out);
#define hood_sim_config_default(out) hood_sim_config_init((out), sizeof *(out))

/* The body of a scene. `positions`: 3 * n_vertices floats, the body at the first frame (m).
 * `indices`: 3 * n_faces. `omitted` (optional, NULL for none): n_vertices flags, nonzero = the
 * vertex never collides (e.g. hands). */
typedef struct hood_body_desc {
    uint32_t struct_size; /* sizeof(hood_body_desc) (see Conventions) */
    const float *positions;
    size_t n_vertices;
    const uint32_t *indices;
    size_t n_faces;
    const uint8_t *omitted;
} hood_body_desc;

typedef struct hood_sim hood_sim;

/* A simulation of `garment` (starting at its rest positions) on `body` (optional: NULL for no
 * body) driven by `model`. `config` NULL means the defaults. The sim keeps copies of the garment
 * and body; it borrows the model (see hood_model_free). */
HOOD_API hood_status HOOD_CALL hood_sim_new(const hood_model *model, const hood_garment *garment,
                                            const hood_body_desc *body, const hood_sim_config *config,
                                            hood_sim **out);
/* Frees a sim (NULL: nothing to do); HOOD_ERR_BUSY, freeing nothing, while another thread steps it. */
HOOD_API hood_status HOOD_CALL hood_sim_free(hood_sim *sim);

/* The last network step's solver refinement (HOOD_EFFECT_REFINE; HOOD_ERR_UNSUPPORTED_EFFECT when
 * it is off; also the solver step mode's solve): accepted L-BFGS iterations and the objective (J)
 * at the network's prediction and after. All zero before the first refined step; the start-up
 * step is not refined. With a time budget (solver_budget_us), the step's wall time by the sim's
 * clock from its start to the end of its solve: a budget too small for the set-up and one
 * iteration cannot be kept (at least one iteration runs), and used_ns > budget_ns says so, as
 * HOOD_STEP_OVER_BUDGET does. */
typedef struct hood_refinement {
    uint32_t struct_size; /* sizeof(hood_refinement), set by the caller (see Conventions) */
    uint32_t iterations;
    float energy_before;
    float energy_after;
    uint64_t budget_ns; /* the time budget of a step, ns (0: none) */
    uint64_t used_ns;   /* the step's time, ns (0 without a budget) */
} hood_refinement;
HOOD_API hood_status HOOD_CALL hood_sim_last_refinement(const hood_sim *sim, hood_refinement *out);
/* Garment vertices of the sim. */
HOOD_API hood_status HOOD_CALL hood_sim_vertex_count(const hood_sim *sim, size_t *out);
/* Body vertices the sim expects per step (0 without a body or without HOOD_EFFECT_BODY_COLLISION). */
HOOD_API hood_status HOOD_CALL hood_sim_body_vertex_count(const hood_sim *sim, size_t *out);

/* Orientation and resolution of the sim's body at its first frame. hood_sim_new refuses a body
 * wound inside out (faces clockwise seen from outside, as a change of handedness gives: negative
 * signed volume) with HOOD_ERR_INSIDE_OUT. It accepts a body too coarse for the body edges (their
 * radius is 3 cm: once the median face edge exceeds sqrt(3) * 3 cm, typical faces have points no
 * body vertex reaches, and unpinned cloth can fall through between vertices); check too_coarse
 * after creation and warn, or use a finer body. HOOD_ERR_UNSUPPORTED_EFFECT without a body or
 * body collision. */
typedef struct hood_body_survey {
    uint32_t struct_size; /* sizeof(hood_body_survey), set by the caller (see Conventions) */
    float volume;       /* signed volume, m^3 (of an open mesh, an estimate) */
    float median_edge;  /* m */
    float longest_edge; /* m */
    uint32_t too_coarse; /* 1: median_edge > sqrt(3) * 0.03 m; else 0 */
} hood_body_survey;
HOOD_API hood_status HOOD_CALL hood_sim_body_survey(const hood_sim *sim, hood_body_survey *out);

/* Advances one frame. `body_next`: the body's vertices at the next frame, 3 * n_body_vertices
 * floats (NULL with 0 when the sim has no body). `garment_out`: receives the garment's new
 * positions, 3 * n_garment_vertices floats. Wrong counts give HOOD_ERR_SIZE_MISMATCH; a
 * non-finite body vertex gives HOOD_ERR_NON_FINITE; on any error the state is unchanged and
 * `garment_out` is not written. */
HOOD_API hood_status HOOD_CALL hood_sim_step(hood_sim *sim, const float *body_next, size_t n_body_vertices,
                                             float *garment_out, size_t n_garment_vertices);

/* What the last successful hood_sim_step did, as HOOD_STEP_* flags (0 before the first step; a
 * refused step leaves them). A teleported or sleeping step does nothing else; the other flags may
 * combine. The calls that place the garment without a step report as follows: after
 * hood_sim_teleport, HOOD_STEP_TELEPORTED alone (the garment moved as an automatic teleport moves
 * it); after hood_sim_reset and hood_sim_load_state, 0, as before the first step (no step has run
 * from the new state: a loaded state does not bring the saving sim's flags). Refused, these calls
 * leave the flags too. After hood_driver_update: the flags of the last model step it ran. */
#define HOOD_STEP_TELEPORTED 1u    /* the garment was moved rigidly instead of stepped: the body
                                      jumped beyond teleport_threshold (its best-fit rigid motion),
                                      or hood_sim_teleport was called */
#define HOOD_STEP_SLEPT 2u         /* sleeping: body and garment at rest, the step was skipped */
#define HOOD_STEP_STARTUP 4u       /* the start-up (relaxation) pass ran before the regular one */
#define HOOD_STEP_SPEED_LIMITED 8u /* the body's centroid moved beyond speed_limit: the garment was
                                      carried by the excess */
#define HOOD_STEP_REFINED 16u      /* a refinement ran (HOOD_EFFECT_REFINE), or the solver step
                                      mode's solve */
#define HOOD_STEP_PROJECTED 32u    /* the collision projection moved at least one vertex */
#define HOOD_STEP_OVER_BUDGET 64u  /* the solver step mode's step took longer than its time budget
                                      (solver_budget_us; hood_refinement says by how much) */
#define HOOD_STEP_TETHERED 128u    /* a body tether pulled at least one vertex back */
HOOD_API hood_status HOOD_CALL hood_sim_last_effects(const hood_sim *sim, uint32_t *flags);

/* Copies the current garment positions (3 * n_vertices floats). */
HOOD_API hood_status HOOD_CALL hood_sim_positions(const hood_sim *sim, float *out, size_t n_vertices);
/* Copies the current garment velocities (m/frame, 3 * n_vertices floats). */
HOOD_API hood_status HOOD_CALL hood_sim_velocities(const hood_sim *sim, float *out, size_t n_vertices);
/* Copies the vertex normals of the current positions (needs HOOD_EFFECT_NORMALS, else
 * HOOD_ERR_UNSUPPORTED_EFFECT). */
HOOD_API hood_status HOOD_CALL hood_sim_normals(const hood_sim *sim, float *out, size_t n_vertices);

/* Targets of the pinned vertices at the next frame: 3 * n_vertices floats, one per garment
 * vertex (only pinned entries are read and must be finite). Without a call pinned vertices keep
 * their last target (initially the rest position). */
HOOD_API hood_status HOOD_CALL hood_sim_set_pin_targets(hood_sim *sim, const float *targets, size_t n_vertices);

/* Restarts from `positions` (3 * n_vertices floats) with zero velocity; the start-up step runs
 * again if configured. `body_positions` (optional, NULL with 0 to keep the current body): the
 * body's vertices now, used as both previous and current frame (a body at rest). Pinned
 * vertices' targets become their given positions. hood_sim_last_effects then gives 0. */
HOOD_API hood_status HOOD_CALL hood_sim_reset(hood_sim *sim, const float *positions, size_t n_vertices,
                                              const float *body_positions, size_t n_body_vertices);

/* Places a garment authored in the rest pose on the body, as the Rust scenes start theirs
 * (hood::solve::push_out_of, bitwise): every unpinned vertex closer than 2 mm
 * (hood::solve::INITIAL_CLEARANCE) to the plane of its nearest body face (the face whose centroid
 * is nearest; omitted vertices do not matter here), or behind that plane, moves along the face's
 * normal to 2 mm in front of it; every other vertex stays. `body`: as for hood_sim_new, at the
 * frame the sim starts from (wound inside out: HOOD_ERR_INSIDE_OUT). `positions`: 3 * n_vertices
 * floats (n_vertices at most HOOD_MAX_VERTICES, else HOOD_ERR_CAPACITY_EXCEEDED), all finite (else HOOD_ERR_NON_FINITE), read and overwritten in place; they must not
 * overlap the body's arrays or `pinned` (HOOD_ERR_BAD_POINTER). `pinned` (optional, NULL for
 * none): n_vertices flags, nonzero = the vertex stays. `moved` (optional, NULL to ignore):
 * receives how many vertices moved. On error neither `positions` nor `moved` is written. Needs no
 * handle; any thread. Typical use: hood_sim_new with the garment, then hood_sim_reset from the
 * pushed-out positions (the garment's rest shape, which sets its cloth's lengths, stays as
 * authored). */
HOOD_API hood_status HOOD_CALL hood_garment_push_out(const hood_body_desc *body, float *positions, size_t n_vertices,
                                                     const uint8_t *pinned, size_t *moved);

/* The whole state between steps as bytes, for save games, rollback netcode and LOD swaps:
 * garment positions and velocities, pin targets, the body's previous and current frames, whether
 * the start-up step has run, the sleeping count and the speed limit's carry (a versioned,
 * little-endian layout with a CRC-32; the same bytes on every platform). A sim of the same
 * garment and body that loads them continues bitwise as the saving sim would have (the
 * configuration is the loading sim's own). hood_sim_state_size gives the exact byte count;
 * hood_sim_save_state needs exactly that many bytes (else HOOD_ERR_SIZE_MISMATCH).
 * hood_sim_load_state refuses bytes that are not a saved state of this format, fail their
 * checksum or are truncated (HOOD_ERR_CORRUPT_DATA), come from another garment or body
 * (HOOD_ERR_SIZE_MISMATCH) or hold a non-finite value (HOOD_ERR_NON_FINITE), and then changes
 * nothing. After a load, hood_sim_last_effects gives 0 (the flags are not part of the state). */
HOOD_API hood_status HOOD_CALL hood_sim_state_size(const hood_sim *sim, size_t *out);
HOOD_API hood_status HOOD_CALL hood_sim_save_state(const hood_sim *sim, uint8_t *out, size_t len);
HOOD_API hood_status HOOD_CALL hood_sim_load_state(hood_sim *sim, const uint8_t *bytes, size_t len);

/* Moves the garment rigidly without simulating (a cut, a respawn, a character teleported):
 * every garment position and pin target p becomes R p + t, every velocity v becomes R v, so the
 * garment keeps its shape and motion relative to the body. `rotation`: 9 floats, row-major 3x3,
 * a proper rotation (orthonormal within 1e-3, determinant +1; else HOOD_ERR_OUT_OF_RANGE), NULL
 * for the identity. `translation`: 3 floats (m), NULL for none. The body is then at rest at
 * `body_now` (3 * n_body_vertices floats: its vertices now, as previous and current frame), or,
 * with NULL and 0, at its current vertices moved by the same motion. Later hood_sim_step calls
 * pass the body in the moved frame. hood_sim_last_effects then gives HOOD_STEP_TELEPORTED. */
HOOD_API hood_status HOOD_CALL hood_sim_teleport(hood_sim *sim, const float *rotation, const float *translation,
                                                 const float *body_now, size_t n_body_vertices);

/* ---- Fixed-step driver ------------------------------------------------------------------- */

/* The model runs at 30 Hz; an engine runs at its own frame rate. A driver advances a sim by
 * engine frames of any length: each hood_driver_update runs as many hood_sim_step calls as 30 Hz
 * frames were crossed, with the body linearly interpolated to each frame's time, and writes the
 * garment interpolated between the last two model frames to engine time (one model frame behind,
 * as fixed-step rendering is). Never feed the model another time step: this is how to run it at
 * 60 or 144 Hz. The same as the Rust hood::sim::FixedStep, bitwise. */
typedef struct hood_driver hood_driver;

/* A driver of `sim`, starting at a model frame with the body and garment where the sim has them.
 * The driver names the sim, it does not own it: free the driver before or after the sim (updates
 * of a driver whose sim was freed give HOOD_ERR_INVALID_HANDLE). Make a new driver after
 * hood_sim_reset, hood_sim_teleport or hood_sim_load_state, which its interpolation does not see.
 * The sim may also be stepped directly, but not both ways in one frame. */
HOOD_API hood_status HOOD_CALL hood_driver_new(hood_sim *sim, hood_driver **out);
/* Frees a driver (NULL: nothing to do); HOOD_ERR_BUSY while another thread updates it. */
HOOD_API hood_status HOOD_CALL hood_driver_free(hood_driver *driver);
/* Advances engine time by `dt` seconds (finite, >= 0, else HOOD_ERR_OUT_OF_RANGE; over 1 s it
 * is simulated as 1 s, 30 model steps, as engines clamp their time step after a hitch). `body_now`:
 * the body's vertices at the new engine time, 3 * n_body_vertices floats (NULL with 0 without a
 * body). `garment_out`: receives the interpolated garment, 3 * n_garment_vertices floats. Bad
 * input is refused before any step; a step's error ends the update with that status (the steps
 * before it stay done). The sim is claimed as by hood_sim_step (HOOD_ERR_BUSY while another
 * thread uses it); one driver is updated by one thread at a time (else HOOD_ERR_BUSY). */
HOOD_API hood_status HOOD_CALL hood_driver_update(hood_driver *driver, float dt, const float *body_now,
                                                  size_t n_body_vertices, float *garment_out,
                                                  size_t n_garment_vertices);
/* Model steps the driver has taken. */
HOOD_API hood_status HOOD_CALL hood_driver_model_steps(const hood_driver *driver, uint64_t *out);

/* ---- Executor (an engine's job system) --------------------------------------------------- */

/* One task of a step: call task(ctx, i). */
typedef void (HOOD_CALL *hood_task_fn)(void *ctx, uint32_t index);

/* `run(user, n_tasks, task, ctx)` must call task(ctx, i) exactly once for every i in
 * [0, n_tasks), from any threads, and return only after every call has returned; it must not
 * throw (wrap a C++ job system's run in try/catch). The library refuses a second call of an index
 * and an index out of range (the step then fails with HOOD_ERR_PANIC and leaves the state
 * unchanged); returning before every task has returned is undefined behaviour. `parallelism`: how many
 * tasks are worth splitting work into (0 counts as 1). `user` is passed back unchanged; it must
 * stay valid while the sim uses the executor and be usable from the thread stepping the sim.
 * `run` is declared with HOOD_CALL (see Linkage and calling convention). */
typedef struct hood_executor {
    uint32_t struct_size; /* sizeof(hood_executor) (see Conventions) */
    void *user;
    uint32_t parallelism;
    void (HOOD_CALL *run)(void *user, uint32_t n_tasks, hood_task_fn task, void *ctx);
} hood_executor;

/* Plugs in an executor for the step's parallel parts (the struct is copied). NULL restores the
 * sim's own (config.threads). This allocates per-task scratch; steps do not allocate. */
HOOD_API hood_status HOOD_CALL hood_sim_set_executor(hood_sim *sim, const hood_executor *executor);

#ifdef __cplusplus
} /* extern "C" */
#endif

#endif /* HOOD_H */
