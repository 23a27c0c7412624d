// MPI, when qdo is built with it (CMake option QDO_MPI, on where Debian's libopenmpi-dev is found)
// and the process was started by an MPI launcher (mpirun, srun). Everything else in qdo sees only
// this header: no MPI type leaks out, and a build without MPI compiles the same callers.
//
// A process started without a launcher never initialises MPI (no singleton start-up cost), so
// `qdo sweep` and `qdo design` run as before; World::active() is then false and size() is 1.
#pragma once
#include <cstddef>
#include <cstdint>
#include <string>

namespace qdo::mpi {

// True when this qdo was built with MPI.
bool built_with_mpi();
// The world size an MPI launcher announced in the environment (OMPI_COMM_WORLD_SIZE, PMI_SIZE or
// PMIX_SIZE / SLURM_NTASKS under srun --mpi), 1 when none did.
int launched_size();

// A message of the sweep's dispatcher: a tag and one integer.
struct Message {
  int source = -1;
  int tag = 0;
  std::int64_t value = 0;
};

// The MPI world of this process: MPI_Init_thread (MPI_THREAD_SERIALIZED: one thread at a time
// calls MPI, the sweep's dispatcher thread on rank 0 included) on construction when a launcher
// started the process, MPI_Finalize on destruction. One per process (a second is a logic error).
// Construction throws InputError when a launcher started N > 1 processes and qdo has no MPI:
// each would otherwise run the whole job on its own.
class World {
 public:
  World();
  ~World();
  World(const World&) = delete;
  World& operator=(const World&) = delete;

  bool active() const { return active_; }    // MPI initialised (size() may still be 1)
  int rank() const { return rank_; }
  int size() const { return size_; }
  int local_rank() const { return local_rank_; }   // rank among the processes of this node
  int local_size() const { return local_size_; }

  void barrier() const;
  // Element-wise sum over all ranks, in place (every rank gets the sum). n elements of `data`.
  void allreduce_sum(double* data, std::size_t n) const;
  void allreduce_sum(float* data, std::size_t n) const;
  // Rank 0's value on every rank.
  void broadcast(std::string& text) const;
  void broadcast(std::int64_t& value) const;
  // Point to point: one integer with a tag (tags 0..32767).
  void send(int dest, int tag, std::int64_t value) const;
  Message receive_any() const;                 // blocks for the next message from any rank
  bool poll(Message& m) const;                 // a message if one has arrived (MPI_Iprobe), else false
  // Ends every rank of the job (MPI_Abort); for a rank that cannot go on.
  [[noreturn]] void abort(int code) const;

 private:
  bool active_ = false;
  int rank_ = 0, size_ = 1, local_rank_ = 0, local_size_ = 1;
};

// The process's World while one exists, else nullptr (library code asks; the tool's main makes
// it). Library code that works together with the other ranks (run_design's data-parallel
// training) asks here; on a thread inside a Solo it gets nullptr.
const World* world();

// Work this thread does alone while the other ranks do other work (a sweep's cells, each rank its
// own): while a Solo lives, world() returns nullptr on this thread, so that a run trains in this
// process alone. Nests.
class Solo {
 public:
  Solo();
  ~Solo();
  Solo(const Solo&) = delete;
  Solo& operator=(const Solo&) = delete;
};

}  // namespace qdo::mpi
