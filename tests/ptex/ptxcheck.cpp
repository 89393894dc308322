// ptxcheck: reads a Ptex file with Disney's reference library and answers queries from
// stdin, one line per query, values printed with 9 significant digits (exact for f32).
// Built by tests/ptex.rs together with ptxinfo (../shared/tools/ptex/build.sh).
//
//   data F ULOG2 VLOG2   texels of face F at that resolution (full: level 0; smaller:
//                        the stored reductions or the reader's own), channel-interleaved
//   const F              the face's constant value (its smallest reduction's mean)
//   filter F U V         bilinear filter at (U, V) of face F, blending across face edges
//   noblend F U V        the same without edge blending (clamped to the face)
//
// `ptxcheck FILE premultiply` opens the file as renderers do for textures with alpha:
// colour multiplied by alpha at every level (the stored reductions already are).
#include <cstdio>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>
#include "Ptexture.h"

using namespace Ptex;

static void print(const std::vector<float>& v) {
    for (size_t i = 0; i < v.size(); i++) printf(i ? " %.9g" : "%.9g", v[i]);
    printf("\n");
}

int main(int argc, char** argv) {
    if (argc < 2 || argc > 3) {
        fprintf(stderr, "usage: ptxcheck FILE.ptx [premultiply] < queries\n");
        return 2;
    }
    Ptex::String error;
    PtexTexture* tx = PtexTexture::open(argv[1], error, argc == 3);
    if (!tx) {
        fprintf(stderr, "%s\n", error.c_str());
        return 1;
    }
    if (tx->dataType() != dt_float) {
        fprintf(stderr, "ptxcheck: only float textures\n");
        return 1;
    }
    const int nch = tx->numChannels();
    PtexFilter* blend = PtexFilter::getFilter(tx, PtexFilter::Options(PtexFilter::f_bilinear));
    PtexFilter* noblend =
        PtexFilter::getFilter(tx, PtexFilter::Options(PtexFilter::f_bilinear, false, 0, true));
    std::string line;
    while (std::getline(std::cin, line)) {
        std::istringstream in(line);
        std::string cmd;
        int face = 0;
        in >> cmd >> face;
        if (face < 0 || face >= tx->numFaces()) {
            printf("error: face out of range\n");
        } else if (cmd == "data") {
            int ul = 0, vl = 0;
            in >> ul >> vl;
            Res r((int8_t)ul, (int8_t)vl);
            std::vector<float> buf(size_t(r.size()) * nch);
            tx->getData(face, buf.data(), 0, r);
            print(buf);
        } else if (cmd == "const") {
            std::vector<float> px(nch);
            tx->getPixel(face, 0, 0, px.data(), 0, nch, Res(0, 0));
            print(px);
        } else if (cmd == "filter" || cmd == "noblend") {
            float u = 0, v = 0;
            in >> u >> v;
            std::vector<float> px(nch);
            (cmd == "filter" ? blend : noblend)->eval(px.data(), 0, nch, face, u, v, 0, 0, 0, 0);
            print(px);
        } else {
            printf("error: unknown query\n");
        }
        fflush(stdout);
    }
    blend->release();
    noblend->release();
    tx->release();
    return 0;
}
