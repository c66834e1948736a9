/* Positioned reads of DEM records for the Fortran core (pi_io.f90).
 *
 * POSIX pread() reads at an offset without moving a shared file position, so
 * any number of threads (OpenMP or Python) may read one descriptor, and one
 * file may be open several times at once -- which Fortran units forbid.
 * Each function returns a negative value on failure and never prints.
 */
#define _FILE_OFFSET_BITS 64
#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>

/* Close-on-exec: a program started (by another thread) while a call reads the file must not
 * inherit the descriptor (an independent review, 2026-12-05). */
int pi_io_open(const char *path) {
  int fd;
  do {
    fd = open(path, O_RDONLY | O_CLOEXEC);
  } while (fd < 0 && errno == EINTR);
  return fd;
}

int pi_io_close(int fd) { return close(fd); }

int64_t pi_io_size(int fd) {
  struct stat st;
  if (fstat(fd, &st) != 0) return -1;
  return (int64_t)st.st_size;
}

/* Read exactly n bytes at byte offset `offset`; 0 on success, -1 otherwise. */
int pi_io_pread(int fd, void *buf, int64_t n, int64_t offset) {
  char *p = (char *)buf;
  while (n > 0) {
    ssize_t got = pread(fd, p, (size_t)n, (off_t)offset);
    if (got < 0 && errno == EINTR) continue; /* a signal before any byte: read again */
    if (got <= 0) return -1;
    p += got;
    n -= got;
    offset += got;
  }
  return 0;
}

#include <sys/mman.h>

/* Map `size` bytes of the open file read-only; NULL on failure. */
void *pi_io_map(int fd, int64_t size) {
  void *p = mmap(NULL, (size_t)size, PROT_READ, MAP_SHARED, fd, 0);
  return p == MAP_FAILED ? NULL : p;
}

int pi_io_unmap(void *p, int64_t size) { return munmap(p, (size_t)size); }
