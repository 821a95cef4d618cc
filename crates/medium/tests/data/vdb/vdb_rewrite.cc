// Rewrites a .vdb written by make_vdb.py with what the Python binding cannot choose: the
// compression (zip, none, blosc) and double-precision grids. Built by make_vdb.py with g++
// against Debian's libopenvdb-dev; it changes no value, so the script's expected values hold.
//
// usage: vdb_rewrite IN OUT {zip|none|blosc} [double]
#include <openvdb/openvdb.h>
#include <openvdb/io/File.h>
#include <cstring>
#include <iostream>

int main(int argc, char** argv)
{
    if (argc < 4) {
        std::cerr << "usage: vdb_rewrite IN OUT {zip|none|blosc} [double]\n";
        return 2;
    }
    openvdb::initialize();
    openvdb::io::File in(argv[1]);
    in.open();
    openvdb::GridPtrVecPtr grids = in.getGrids();
    openvdb::MetaMap::Ptr fileMeta = in.getMetadata();
    in.close();

    const bool toDouble = argc > 4 && std::strcmp(argv[4], "double") == 0;
    openvdb::GridPtrVec out;
    for (auto& base : *grids) {
        auto f = openvdb::gridPtrCast<openvdb::FloatGrid>(base);
        if (!toDouble || !f) { out.push_back(base); continue; }
        // Same topology (voxels and tiles, active or not) with every value widened exactly.
        auto d = openvdb::DoubleGrid::create(double(f->background()));
        d->setTransform(f->transform().copy());
        d->insertMeta(*f);
        d->setName(f->getName());
        auto acc = d->getAccessor();
        for (auto it = f->cbeginValueAll(); it; ++it) {
            if (it.isVoxelValue()) {
                acc.setValue(it.getCoord(), double(*it));
                acc.setActiveState(it.getCoord(), it.isValueOn());
            } else {
                d->tree().addTile(it.getLevel(), it.getCoord(), double(*it), it.isValueOn());
            }
        }
        out.push_back(d);
    }

    openvdb::io::File o(argv[2]);
    const std::string mode = argv[3];
    uint32_t c = openvdb::io::COMPRESS_ACTIVE_MASK;
    if (mode == "zip") c |= openvdb::io::COMPRESS_ZIP;
    else if (mode == "blosc") c |= openvdb::io::COMPRESS_BLOSC;
    else if (mode != "none") { std::cerr << "unknown compression " << mode << "\n"; return 2; }
    o.setCompression(c);
    o.write(out, *fileMeta);
    o.close();
    return 0;
}
