// drape.cpp: the drape.c scene from C++ (RAII handles, a std::thread job system as the executor).
//
//   drape_cpp MODEL.hood [GRID]
//
// Build (Linux, from the repository root, after `cargo build -p hood-ffi`):
//
//   c++ -std=c++17 -Wall -Wextra -Werror -Iffi/include ffi/examples/drape.cpp
//       target/debug/libhood_ffi.a -lpthread -ldl -lm -o drape_cpp
#include "hood.h"

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace {

constexpr int kSteps = 60;
constexpr float kPi = 3.14159265358979f;

void check(hood_status s, const char *what) {
    if (s != HOOD_OK) {
        throw std::runtime_error(std::string(what) + " failed: " + hood_status_string(s) + ": " + hood_last_error());
    }
}

struct ModelFree {
    void operator()(hood_model *m) const { hood_model_free(m); }
};
struct GarmentFree {
    void operator()(hood_garment *g) const { hood_garment_free(g); }
};
struct SimFree {
    void operator()(hood_sim *s) const { hood_sim_free(s); }
};

// Bytes at a HOOD_MODEL_ALIGN-aligned address inside an over-allocated vector.
struct AlignedBytes {
    std::vector<std::uint8_t> storage;
    std::size_t offset = 0, len = 0;
    const std::uint8_t *data() const { return storage.data() + offset; }
};

AlignedBytes read_file(const char *path) {
    std::ifstream f(path, std::ios::binary | std::ios::ate);
    if (!f) throw std::runtime_error(std::string("cannot open ") + path);
    AlignedBytes b;
    b.len = static_cast<std::size_t>(f.tellg());
    b.storage.resize(b.len + HOOD_MODEL_ALIGN);
    auto addr = reinterpret_cast<std::uintptr_t>(b.storage.data());
    b.offset = (HOOD_MODEL_ALIGN - addr % HOOD_MODEL_ALIGN) % HOOD_MODEL_ALIGN;
    f.seekg(0);
    f.read(reinterpret_cast<char *>(b.storage.data() + b.offset), static_cast<std::streamsize>(b.len));
    if (!f) throw std::runtime_error(std::string("cannot read ") + path);
    return b;
}

// A minimal job system: one persistent helper thread; each run() shares the tasks between the
// calling thread and the helper, which claim indices from a shared counter.
class HelperPool {
  public:
    HelperPool() : worker_([this] { loop(); }) {}
    ~HelperPool() {
        {
            std::lock_guard<std::mutex> lock(m_);
            stop_ = true;
        }
        wake_.notify_all();
        worker_.join();
    }
    HelperPool(const HelperPool &) = delete;
    HelperPool &operator=(const HelperPool &) = delete;

    // HOOD_CALL: the calling convention the library calls `run` with (see hood.h).
    static void HOOD_CALL run(void *user, std::uint32_t n, hood_task_fn task, void *ctx) {
        static_cast<HelperPool *>(user)->run_job(n, task, ctx);
    }

  private:
    void run_job(std::uint32_t n, hood_task_fn task, void *ctx) {
        next_.store(0);
        {
            std::lock_guard<std::mutex> lock(m_);
            task_ = task;
            ctx_ = ctx;
            n_ = n;
            busy_ = true;
            ++generation_;
        }
        wake_.notify_all();
        claim(task, ctx, n);
        std::unique_lock<std::mutex> lock(m_);
        done_.wait(lock, [this] { return !busy_; });
    }

    void claim(hood_task_fn task, void *ctx, std::uint32_t n) {
        for (std::uint32_t i; (i = next_.fetch_add(1)) < n;) task(ctx, i);
    }

    void loop() {
        std::uint64_t seen = 0;
        std::unique_lock<std::mutex> lock(m_);
        for (;;) {
            wake_.wait(lock, [&] { return stop_ || generation_ != seen; });
            if (stop_) return;
            seen = generation_;
            hood_task_fn task = task_;
            void *ctx = ctx_;
            std::uint32_t n = n_;
            lock.unlock();
            claim(task, ctx, n);
            lock.lock();
            busy_ = false;
            done_.notify_all();
        }
    }

    std::mutex m_;
    std::condition_variable wake_, done_;
    std::atomic<std::uint32_t> next_{0};
    hood_task_fn task_ = nullptr;
    void *ctx_ = nullptr;
    std::uint32_t n_ = 0;
    std::uint64_t generation_ = 0;
    bool busy_ = false, stop_ = false;
    std::thread worker_;  // last: starts once the members above exist
};

void ellipsoid(int rings, int segs, const float r[3], std::vector<float> &v, std::vector<std::uint32_t> &f) {
    v = {0.0f, r[1], 0.0f};
    for (int i = 0; i < rings; i++) {
        float th = kPi * float(i + 1) / float(rings + 1);
        for (int s = 0; s < segs; s++) {
            float ph = 2.0f * kPi * float(s) / float(segs);
            v.insert(v.end(), {r[0] * std::sin(th) * std::cos(ph), r[1] * std::cos(th), r[2] * std::sin(th) * std::sin(ph)});
        }
    }
    v.insert(v.end(), {0.0f, -r[1], 0.0f});
    auto id = [&](int ring, int seg) { return std::uint32_t(1 + ring * segs + seg % segs); };
    auto south = std::uint32_t(1 + rings * segs);
    for (int s = 0; s < segs; s++) f.insert(f.end(), {0u, id(0, s + 1), id(0, s)});
    for (int i = 0; i + 1 < rings; i++) {
        for (int s = 0; s < segs; s++) {
            auto a = id(i, s), b = id(i, s + 1), c = id(i + 1, s + 1), d = id(i + 1, s);
            f.insert(f.end(), {a, b, c, a, c, d});
        }
    }
    for (int s = 0; s < segs; s++) f.insert(f.end(), {south, id(rings - 1, s), id(rings - 1, s + 1)});
}

void grid(int n, float size, float y, std::vector<float> &v, std::vector<std::uint32_t> &f) {
    for (int j = 0; j < n; j++) {
        for (int i = 0; i < n; i++) {
            v.insert(v.end(), {size * (float(i) / float(n - 1) - 0.5f), y, size * (float(j) / float(n - 1) - 0.5f)});
        }
    }
    for (int j = 0; j + 1 < n; j++) {
        for (int i = 0; i + 1 < n; i++) {
            auto a = std::uint32_t(j * n + i), b = a + 1, c = a + 1 + std::uint32_t(n), d = a + std::uint32_t(n);
            f.insert(f.end(), {a, d, c, a, c, b});
        }
    }
}

int run(int argc, char **argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s MODEL.hood [GRID]\n", argv[0]);
        return 2;
    }
    int n = argc > 2 ? std::max(2, std::atoi(argv[2])) : 16;
    if (hood_version() != HOOD_VERSION) throw std::runtime_error("header and library versions differ");
    std::printf("hood %s\n", hood_version_string());

    AlignedBytes bytes = read_file(argv[1]);  // must outlive the model (declared first, dies last)
    hood_model *raw_model = nullptr;
    check(hood_model_load(bytes.data(), bytes.len, &raw_model), "hood_model_load");
    std::unique_ptr<hood_model, ModelFree> model(raw_model);

    std::vector<float> rest, body_rest;
    std::vector<std::uint32_t> faces, body_faces;
    grid(n, 0.6f, 0.32f, rest, faces);
    const float radii[3] = {0.25f, 0.3f, 0.25f};
    ellipsoid(16, 24, radii, body_rest, body_faces);
    std::size_t nv = rest.size() / 3, nb = body_rest.size() / 3;
    std::vector<std::uint8_t> pinned(nv, 0);
    pinned[0] = 1;
    pinned[std::size_t(n - 1)] = 1;

    hood_garment *raw_garment = nullptr;
    check(hood_garment_new(rest.data(), nv, faces.data(), faces.size() / 3, nullptr, 0, pinned.data(), &raw_garment),
          "hood_garment_new");
    std::unique_ptr<hood_garment, GarmentFree> garment(raw_garment);

    hood_body_desc bd{sizeof(hood_body_desc), body_rest.data(), nb, body_faces.data(), body_faces.size() / 3, nullptr};
    hood_sim_config cfg;
    hood_sim_config_default(&cfg);
    hood_sim *raw_sim = nullptr;
    check(hood_sim_new(model.get(), garment.get(), &bd, &cfg, &raw_sim), "hood_sim_new");
    std::unique_ptr<hood_sim, SimFree> sim(raw_sim);  // declared after the model: freed first

    HelperPool pool;  // dies before the sim, which is why it is unplugged after the last step
    hood_executor exec{sizeof(hood_executor), &pool, 2, &HelperPool::run};
    check(hood_sim_set_executor(sim.get(), &exec), "hood_sim_set_executor");
    std::printf("garment: %zu vertices, body: %zu vertices\n", nv, nb);

    // A garment authored in the rest pose may start in the body: push it out onto the body's
    // first frame and start the sim from there (this cloth hangs 2 cm above the body: nothing moves).
    std::vector<float> body(body_rest.size()), out(rest);
    std::size_t moved = 0;
    check(hood_garment_push_out(&bd, out.data(), nv, pinned.data(), &moved), "hood_garment_push_out");
    if (moved > 0) check(hood_sim_reset(sim.get(), out.data(), nv, nullptr, 0), "hood_sim_reset");
    std::printf("pushed out: %zu vertices\n", moved);
    auto t0 = std::chrono::steady_clock::now();
    for (int t = 1; t <= kSteps; t++) {
        float dx = 0.01f * std::sin(0.3f * float(t));
        for (std::size_t i = 0; i < nb; i++) {
            body[3 * i] = body_rest[3 * i] + dx;
            body[3 * i + 1] = body_rest[3 * i + 1];
            body[3 * i + 2] = body_rest[3 * i + 2];
        }
        check(hood_sim_step(sim.get(), body.data(), nb, out.data(), nv), "hood_sim_step");
    }
    double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();

    float lo[3] = {out[0], out[1], out[2]}, hi[3] = {out[0], out[1], out[2]};
    for (std::size_t i = 1; i < nv; i++) {
        for (int k = 0; k < 3; k++) {
            lo[k] = std::min(lo[k], out[3 * i + std::size_t(k)]);
            hi[k] = std::max(hi[k], out[3 * i + std::size_t(k)]);
        }
    }
    std::printf("steps: %d\n", kSteps);
    std::printf("time: %.3f ms total, %.3f ms/step (wall clock, 2-thread executor)\n", ms, ms / kSteps);
    check(hood_sim_set_executor(sim.get(), nullptr), "hood_sim_set_executor");  // before `pool` dies
    std::printf("bbox: min %.6f %.6f %.6f max %.6f %.6f %.6f\n", double(lo[0]), double(lo[1]), double(lo[2]),
                double(hi[0]), double(hi[1]), double(hi[2]));
    return 0;
}

}  // namespace

int main(int argc, char **argv) {
    try {
        return run(argc, argv);
    } catch (const std::exception &e) {
        std::fprintf(stderr, "%s\n", e.what());
        return 1;
    }
}
