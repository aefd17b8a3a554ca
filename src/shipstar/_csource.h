/* The SHA-256 of a compiled module's C sources, set by setup.py (-DSHIPSTAR_SOURCE_SHA256="..."),
 * exported as the module's SOURCE_SHA256: shipstar._codeid.code_identity() counts it, so a
 * Dask worker whose kernels were built from other sources is refused by the archive's tasks.
 * Included by every compiled module, after Python.h. */
#ifndef SHIPSTAR_CSOURCE_H
#define SHIPSTAR_CSOURCE_H

#ifndef SHIPSTAR_SOURCE_SHA256
#define SHIPSTAR_SOURCE_SHA256 ""
#endif

/* ``m`` (a new module, or NULL) with its SOURCE_SHA256 added; NULL on failure. */
static PyObject *module_with_source_digest(PyObject *m)
{
    if (m != NULL && PyModule_AddStringConstant(m, "SOURCE_SHA256", SHIPSTAR_SOURCE_SHA256) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}

#endif
