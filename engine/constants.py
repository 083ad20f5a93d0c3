"""Physical constants and the engine's tuning thresholds, each defined once.

G             standard gravity [m/s^2]; scenes hang their cloths and rods under it.
CFL_SAFETY    fraction of the estimated stability limit an explicit scene steps at when it is
              sub-stepped to stay stable (dt <= CFL_SAFETY x dt_stable).
SERIAL_BELOW  with more than two threads, below this many vertices the PCG solver runs its whole CG
              loop in one kernel (above it, three parallel launches per iteration that use every
              thread); with one or two threads, at every size. Measured on the 2-core CPU, backward
              Euler on the cloth, ms per CG iteration, when that kernel was serial: 32x32 0.10 vs
              0.60 parallel three-launch; 64x64 0.37 vs 0.84; 128x128 1.52 vs 1.52 (a parallel launch
              costs ~0.1 ms and each ndarray argument ~5 us of Python). On the mesh's two halves
              (WHOLE_SPLIT_FROM) it is ahead at every size on two threads: one backward-Euler step at
              256x256, 14.3 s vs 29.3 s (cloth), 10.1 s vs 16.0 s (membrane).
"""

G = 9.81
CFL_SAFETY = 0.9
SERIAL_BELOW = 20000
# From this many vertices that whole-loop kernel runs on two vertex blocks (the two halves), whose
# phases the threads share (engine.tickets); below it, one block on one thread (a phase's hand-over,
# ~2-5 us on the 2-core CPU, would cost more than the work). Its partial sums follow the blocks, so
# the split depends on the mesh alone and the kernel's result not on the number of threads.
WHOLE_SPLIT_FROM = 512

# Below this many vertices a light per-vertex pass of the implicit step (the copy of x_n, the Newton
# residual, the weight added to the forces, the Newton update, the step's velocities) runs serialized
# on the launching thread: Taichi's CPU parallel loop hands its work to the thread pool and waits for
# it, ~30-40 us per loop on the 2-core CPU (a loop over 4096 vertices: 36 us parallel, 11 us
# serial), more right after PARDISO has had the cores. Measured in the backward-Euler step (Intel
# Xeon, 2 threads, PARDISO; the five passes timed inside the step, serial and parallel steps
# alternating, medians): 64^2 946 -> 750 us per step, 128^2 2631 -> 2386, 181^2 (32761 vertices)
# 4303 either way, 256^2 7428 parallel against 7969 serial.
VERTEX_PASS_SERIAL_BELOW = 1 << 15

# Spring-only models below this many vertices run many explicit steps per kernel launch (one
# serial kernel: a chain or a frame is cheaper to step serially than to launch kernels for).
MANY_STEPS_BELOW = 50000

# The one list of each kind of name (the CLI's choices, the registry and the kernels' method codes
# are all read from these).
EXPLICIT = ("forward-euler", "symplectic-euler", "velocity-verlet")   # explicit integrators
INTEGRATOR_NAMES = EXPLICIT + ("backward-euler",)                    # every registered integrator
SOLVERS = ("pcg", "cholesky", "pardiso", "direct")                   # backward Euler's linear solvers
