#include "qdo/runtime/mpi.hpp"

#include <cstdlib>
#include <limits>
#include <string>
#include <vector>

#include "qdo/runtime/error.hpp"

#ifdef QDO_HAVE_MPI
// The C API alone: OpenMPI and MPICH otherwise pull in their deprecated C++ bindings.
#define OMPI_SKIP_MPICXX 1
#define MPICH_SKIP_MPICXX 1
#include <mpi.h>
#endif

namespace qdo::mpi {

namespace {
const World* g_world = nullptr;

int env_int(const char* name) {
  const char* v = std::getenv(name);
  if (!v || !*v) return 0;
  char* end = nullptr;
  const long n = std::strtol(v, &end, 10);
  return (end && *end == '\0' && n > 0 && n < 1000000) ? int(n) : 0;
}

#ifdef QDO_HAVE_MPI
void check(int rc, const char* what) {
  if (rc != MPI_SUCCESS) {
    char msg[MPI_MAX_ERROR_STRING];
    int len = 0;
    MPI_Error_string(rc, msg, &len);
    throw std::runtime_error(std::string("MPI: ") + what + " failed: " + std::string(msg, std::size_t(len)));
  }
}
// Counts above INT_MAX are sent in pieces.
template <class T>
void allreduce_chunks(T* data, std::size_t n, MPI_Datatype type) {
  const std::size_t chunk = std::size_t(std::numeric_limits<int>::max());
  for (std::size_t i = 0; i < n; i += chunk) {
    const int count = int(std::min(chunk, n - i));
    check(MPI_Allreduce(MPI_IN_PLACE, data + i, count, type, MPI_SUM, MPI_COMM_WORLD), "MPI_Allreduce");
  }
}
#endif
}  // namespace

bool built_with_mpi() {
#ifdef QDO_HAVE_MPI
  return true;
#else
  return false;
#endif
}

int launched_size() {
  for (const char* v : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE"})
    if (const int n = env_int(v)) return n;
  // srun starts ranks with PMI/PMIx variables of its own; SLURM_NTASKS alone (an sbatch script's
  // shell) is no launcher, so it is read only beside SLURM_PROCID.
  if (std::getenv("SLURM_PROCID"))
    if (const int n = env_int("SLURM_NTASKS")) return n;
  return 1;
}

World::World() {
  if (g_world) throw std::logic_error("qdo::mpi::World: one per process");
  const int n = launched_size();
#ifdef QDO_HAVE_MPI
  const bool launched = n > 1 || std::getenv("OMPI_COMM_WORLD_SIZE") || std::getenv("PMIX_RANK") || std::getenv("PMI_RANK");
  if (launched) {
    int provided = 0;
    check(MPI_Init_thread(nullptr, nullptr, MPI_THREAD_SERIALIZED, &provided), "MPI_Init_thread");
    active_ = true;
    if (provided < MPI_THREAD_SERIALIZED) {
      MPI_Finalize();
      active_ = false;
      throw DeviceError("MPI: the library gives thread level " + std::to_string(provided) +
                        "; qdo needs MPI_THREAD_SERIALIZED (" + std::to_string(int(MPI_THREAD_SERIALIZED)) + ")");
    }
    check(MPI_Comm_rank(MPI_COMM_WORLD, &rank_), "MPI_Comm_rank");
    check(MPI_Comm_size(MPI_COMM_WORLD, &size_), "MPI_Comm_size");
    MPI_Comm node;
    check(MPI_Comm_split_type(MPI_COMM_WORLD, MPI_COMM_TYPE_SHARED, rank_, MPI_INFO_NULL, &node), "MPI_Comm_split_type");
    MPI_Comm_rank(node, &local_rank_);
    MPI_Comm_size(node, &local_size_);
    MPI_Comm_free(&node);
  }
#else
  if (n > 1)
    reject("MPI launcher", std::to_string(n) + " processes",
           "1 process: this qdo was built without MPI (install libopenmpi-dev and configure again, "
           "CMake option QDO_MPI), so each process would run the whole job on its own");
#endif
  g_world = this;
}

World::~World() {
#ifdef QDO_HAVE_MPI
  if (active_) MPI_Finalize();
#endif
  g_world = nullptr;
}

namespace {
thread_local int t_solo = 0;
}
const World* world() { return t_solo > 0 ? nullptr : g_world; }
Solo::Solo() { ++t_solo; }
Solo::~Solo() { --t_solo; }

#ifdef QDO_HAVE_MPI
void World::barrier() const {
  if (active_) check(MPI_Barrier(MPI_COMM_WORLD), "MPI_Barrier");
}
void World::allreduce_sum(double* data, std::size_t n) const {
  if (active_ && size_ > 1) allreduce_chunks(data, n, MPI_DOUBLE);
}
void World::allreduce_sum(float* data, std::size_t n) const {
  if (active_ && size_ > 1) allreduce_chunks(data, n, MPI_FLOAT);
}
void World::broadcast(std::string& text) const {
  if (!active_ || size_ < 2) return;
  std::int64_t len = std::int64_t(text.size());
  broadcast(len);
  text.resize(std::size_t(len));
  if (len > std::numeric_limits<int>::max()) throw std::runtime_error("MPI: broadcast of more than 2 GB");
  if (len > 0) check(MPI_Bcast(text.data(), int(len), MPI_CHAR, 0, MPI_COMM_WORLD), "MPI_Bcast");
}
void World::broadcast(std::int64_t& value) const {
  if (active_ && size_ > 1) check(MPI_Bcast(&value, 1, MPI_INT64_T, 0, MPI_COMM_WORLD), "MPI_Bcast");
}
void World::send(int dest, int tag, std::int64_t value) const {
  check(MPI_Send(&value, 1, MPI_INT64_T, dest, tag, MPI_COMM_WORLD), "MPI_Send");
}
Message World::receive_any() const {
  Message m;
  MPI_Status st;
  check(MPI_Recv(&m.value, 1, MPI_INT64_T, MPI_ANY_SOURCE, MPI_ANY_TAG, MPI_COMM_WORLD, &st), "MPI_Recv");
  m.source = st.MPI_SOURCE;
  m.tag = st.MPI_TAG;
  return m;
}
bool World::poll(Message& m) const {
  int flag = 0;
  MPI_Status st;
  check(MPI_Iprobe(MPI_ANY_SOURCE, MPI_ANY_TAG, MPI_COMM_WORLD, &flag, &st), "MPI_Iprobe");
  if (!flag) return false;
  check(MPI_Recv(&m.value, 1, MPI_INT64_T, st.MPI_SOURCE, st.MPI_TAG, MPI_COMM_WORLD, &st), "MPI_Recv");
  m.source = st.MPI_SOURCE;
  m.tag = st.MPI_TAG;
  return true;
}
void World::abort(int code) const {
  if (active_) MPI_Abort(MPI_COMM_WORLD, code);
  std::_Exit(code);
}
#else
void World::barrier() const {}
void World::allreduce_sum(double*, std::size_t) const {}
void World::allreduce_sum(float*, std::size_t) const {}
void World::broadcast(std::string&) const {}
void World::broadcast(std::int64_t&) const {}
void World::send(int, int, std::int64_t) const { throw std::logic_error("qdo::mpi::World::send without MPI"); }
Message World::receive_any() const { throw std::logic_error("qdo::mpi::World::receive_any without MPI"); }
bool World::poll(Message&) const { return false; }
void World::abort(int code) const { std::_Exit(code); }
#endif

}  // namespace qdo::mpi
