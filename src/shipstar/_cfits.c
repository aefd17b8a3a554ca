/* Compiled helper of shipstar/_fitsio.py (plain C99, Python's buffer protocol).
 *
 * swap_xor(buffer, n, itemsize, mask): the n big-endian items of ``itemsize`` bytes (2, 4 or 8)
 * of a FITS image's data, read straight into the (writable) array that will hold them, turned in
 * place into native little-endian order and, for 2- and 4-byte integers stored with the unsigned
 * offset (BZERO 2^15 / 2^31), their sign bit flipped (``mask``): the values astropy returns.  One
 * pass over the pixels in the cache they were just read into, where NumPy's byte-swapped xor into
 * a second array takes two.  Only little-endian hosts call it (_fitsio checks sys.byteorder).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>

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
    if (itemsize == 2) {
        uint16_t *p = b.buf, m = (uint16_t)mask;
        for (Py_ssize_t i = 0; i < n; i++) p[i] = (uint16_t)(((p[i] >> 8) | (p[i] << 8)) ^ m);
    } else if (itemsize == 4) {
        uint32_t *p = b.buf, m = (uint32_t)mask;
        for (Py_ssize_t i = 0; i < n; i++) {
            uint32_t v = p[i];
            p[i] = ((v >> 24) | ((v >> 8) & 0xff00u) | ((v << 8) & 0xff0000u) | (v << 24)) ^ m;
        }
    } else {
        uint64_t *p = b.buf, m = (uint64_t)mask;
        for (Py_ssize_t i = 0; i < n; i++) {
            uint64_t v = p[i], r = 0;
            for (int k = 0; k < 8; k++) r = (r << 8) | ((v >> (8 * k)) & 0xffu);
            p[i] = r ^ m;
        }
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&b);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"swap_xor", py_swap_xor, METH_VARARGS, "Big-endian items to native order in place, xor a mask."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_cfits", "shipstar's FITS reading helper", -1, methods};

PyMODINIT_FUNC PyInit__cfits(void) { return PyModule_Create(&module); }
