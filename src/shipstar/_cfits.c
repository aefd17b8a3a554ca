/* Compiled helper of shipstar/_fitsio.py (plain C99, Python's buffer protocol).
 *
 * swap_xor(buffer, n, itemsize, mask): the n big-endian items of ``itemsize`` bytes (2, 4 or 8)
 * of a FITS image's data, read straight into the (writable) array that will hold them, turned in
 * place into native little-endian order and, for 2- and 4-byte integers stored with the unsigned
 * offset (BZERO 2^15 / 2^31), their sign bit flipped (``mask``): the values astropy returns.  One
 * pass over the pixels in the cache they were just read into, where NumPy's byte-swapped xor into
 * a second array takes two.  Only little-endian hosts call it (_fitsio checks sys.byteorder).
 *
 * read_swap(fd, offset, buffer, n, itemsize, mask) -> bytes read: the n items read from the
 * file descriptor at ``offset`` straight into the buffer and swapped as above, a chunk at a
 * time (READ_CHUNK bytes: the swap finds each chunk still in the cache the read put it in;
 * swapping the whole 2 MB frame after reading it streams it through memory twice more,
 * ~0.05 ms of the ~0.28 ms a 1024 x 1024 frame took); stops at the end of the file (fewer
 * bytes than asked for: the caller refuses the file).  -1 with errno's message as OSError,
 * or -2 where pread is not available (the caller reads and swaps it itself).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include "_csource.h"
#include <stdint.h>
#include <errno.h>
#if defined(__unix__) || defined(__APPLE__)
#include <unistd.h>
#define HAVE_PREAD 1
#endif

#define READ_CHUNK (256 * 1024)

static void swap_items(void *buf, Py_ssize_t n, int itemsize, unsigned long long mask) {
    if (itemsize == 2) {
        uint16_t *p = buf, m = (uint16_t)mask;
        for (Py_ssize_t i = 0; i < n; i++) p[i] = (uint16_t)(((p[i] >> 8) | (p[i] << 8)) ^ m);
    } else if (itemsize == 4) {
        uint32_t *p = buf, m = (uint32_t)mask;
        for (Py_ssize_t i = 0; i < n; i++) {
            uint32_t v = p[i];
            p[i] = ((v >> 24) | ((v >> 8) & 0xff00u) | ((v << 8) & 0xff0000u) | (v << 24)) ^ m;
        }
    } else {
        uint64_t *p = buf, m = (uint64_t)mask;
        for (Py_ssize_t i = 0; i < n; i++) {
            uint64_t v = p[i], r = 0;
            for (int k = 0; k < 8; k++) r = (r << 8) | ((v >> (8 * k)) & 0xffu);
            p[i] = r ^ m;
        }
    }
}

static PyObject *py_swap_xor(PyObject *self, PyObject *args) {
    Py_buffer b;
    Py_ssize_t n;
    int itemsize;
    unsigned long long mask;
    if (!PyArg_ParseTuple(args, "w*niK", &b, &n, &itemsize, &mask)) return NULL;
    if (n < 0 || (itemsize != 2 && itemsize != 4 && itemsize != 8) || b.len < n * itemsize) {
        PyBuffer_Release(&b);
        PyErr_SetString(PyExc_ValueError, "swap_xor: bad sizes");
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    swap_items(b.buf, n, itemsize, mask);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&b);
    Py_RETURN_NONE;
}

static PyObject *py_read_swap(PyObject *self, PyObject *args) {
    int fd, itemsize;
    long long offset;
    Py_buffer b;
    Py_ssize_t n;
    unsigned long long mask;
    if (!PyArg_ParseTuple(args, "iLw*niK", &fd, &offset, &b, &n, &itemsize, &mask)) return NULL;
    if (n < 0 || offset < 0 || (itemsize != 2 && itemsize != 4 && itemsize != 8) || b.len < n * itemsize) {
        PyBuffer_Release(&b);
        PyErr_SetString(PyExc_ValueError, "read_swap: bad sizes");
        return NULL;
    }
#ifdef HAVE_PREAD
    Py_ssize_t total = n * itemsize, done = 0;
    int err = 0;
    Py_BEGIN_ALLOW_THREADS
    char *p = b.buf;
    while (done < total) {
        Py_ssize_t want = total - done < READ_CHUNK ? total - done : READ_CHUNK, got = 0;
        while (got < want) {                        /* a chunk whole (pread may return less) */
            ssize_t r = pread(fd, p + done + got, (size_t)(want - got), (off_t)(offset + done + got));
            if (r < 0) {
                if (errno == EINTR) continue;
                err = errno;
                break;
            }
            if (r == 0) break;                      /* the end of the file */
            got += r;
        }
        if (err) break;
        Py_ssize_t whole = (got / itemsize) * itemsize;
        swap_items(p + done, whole / itemsize, itemsize, mask);
        done += got;
        if (got < want) break;
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&b);
    if (err) {
        errno = err;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    return PyLong_FromSsize_t(done);
#else
    PyBuffer_Release(&b);
    return PyLong_FromLong(-2);
#endif
}

static PyMethodDef methods[] = {
    {"swap_xor", py_swap_xor, METH_VARARGS, "Big-endian items to native order in place, xor a mask."},
    {"read_swap", py_read_swap, METH_VARARGS, "Read big-endian items from a file descriptor and swap them, chunk by chunk."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_cfits", "shipstar's FITS reading helper", -1, methods};

PyMODINIT_FUNC PyInit__cfits(void) { return module_with_source_digest(PyModule_Create(&module)); }
