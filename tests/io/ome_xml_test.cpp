#include "io/ome_xml.h"

#include <gtest/gtest.h>

#include <string>

namespace octoscope::io {
namespace {

using volume::DataType;
using volume::Rgba;

// A minimal valid document around one Pixels element whose attributes and children are given.
std::string Doc(const std::string& pixels_attrs, const std::string& pixels_children = "",
                const std::string& ns = "http://www.openmicroscopy.org/Schemas/OME/2016-06") {
  return "<?xml version=\"1.0\" encoding=\"UTF-8\"?><OME xmlns=\"" + ns +
         "\" UUID=\"urn:uuid:doc\"><Image ID=\"Image:0\" Name=\"img\"><Pixels " + pixels_attrs +
         ">" + pixels_children + "</Pixels></Image></OME>";
}

const char kSizes[] =
    "DimensionOrder=\"XYZCT\" Type=\"uint16\" SizeX=\"4\" SizeY=\"3\" SizeZ=\"2\" SizeC=\"1\" "
    "SizeT=\"1\"";

TEST(OmeXmlTest, ParsesFullImage) {
  std::string xml =
      "<?xml version=\"1.0\" encoding=\"UTF-8\"?><!-- comment -->"
      "<OME xmlns=\"http://www.openmicroscopy.org/Schemas/OME/2016-06\" "
      "UUID=\"urn:uuid:1234\"><Image ID=\"Image:0\" Name=\"first\">"
      "<Pixels DimensionOrder=\"XYCZT\" Type=\"int8\" SizeX=\"439\" SizeY=\"167\" SizeZ=\"5\" "
      "SizeC=\"3\" SizeT=\"7\" PhysicalSizeX=\"0.5\" PhysicalSizeY=\"500\" "
      "PhysicalSizeYUnit=\"nm\" "
      "PhysicalSizeZ=\"2\" PhysicalSizeZUnit=\"mm\">"
      "<Channel ID=\"Channel:0:0\" Name=\"DAPI\" Color=\"-16776961\" SamplesPerPixel=\"1\"/>"
      "<Channel ID=\"Channel:0:1\" Name=\"GFP\" Color=\"16711935\"/>"
      "<Channel ID=\"Channel:0:2\"/>"
      "<TiffData IFD=\"3\" FirstZ=\"1\" FirstC=\"2\" FirstT=\"6\" PlaneCount=\"1\">"
      "<UUID FileName=\"a.ome.tif\">\n  urn:uuid:1234 \n</UUID></TiffData>"
      "<TiffData/>"
      "</Pixels></Image>"
      "<Image ID=\"Image:1\"><Pixels DimensionOrder=\"XYTZC\" Type=\"double\" SizeX=\"1\" "
      "SizeY=\"1\" SizeZ=\"1\" SizeC=\"1\" SizeT=\"1\"/></Image></OME>";
  Result<OmeMetadata> parsed = ParseOmeXml(xml, "x.ome.tif");
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  const OmeMetadata& m = *parsed;
  EXPECT_EQ(m.uuid, "urn:uuid:1234");
  EXPECT_FALSE(m.binary_only.has_value());
  ASSERT_EQ(m.images.size(), 2u);
  EXPECT_EQ(m.images[0].id, "Image:0");
  EXPECT_EQ(m.images[0].name, "first");
  const OmePixels& p = m.images[0].pixels;
  EXPECT_EQ(p.dimension_order, DimensionOrder::kXYCZT);
  EXPECT_EQ(p.type, DataType::kInt8);
  EXPECT_EQ(p.size_x, 439);
  EXPECT_EQ(p.size_y, 167);
  EXPECT_EQ(p.size_z, 5);
  EXPECT_EQ(p.size_c, 3);
  EXPECT_EQ(p.size_time, 7);
  ASSERT_TRUE(p.physical_size_um[0].has_value());
  EXPECT_DOUBLE_EQ(*p.physical_size_um[0], 0.5);
  EXPECT_DOUBLE_EQ(*p.physical_size_um[1], 0.5);
  EXPECT_DOUBLE_EQ(*p.physical_size_um[2], 2000.0);
  ASSERT_EQ(p.channels.size(), 3u);
  EXPECT_EQ(p.channels[0].name, "DAPI");
  // -16776961 = 0xFF0000FF: opaque red.
  EXPECT_EQ(p.channels[0].color, (Rgba{255, 0, 0, 255}));
  EXPECT_EQ(p.channels[0].samples_per_pixel, 1);
  // 16711935 = 0x00FF00FF: opaque green.
  EXPECT_EQ(p.channels[1].color, (Rgba{0, 255, 0, 255}));
  EXPECT_FALSE(p.channels[1].samples_per_pixel.has_value());
  EXPECT_EQ(p.channels[2].name, "");
  EXPECT_FALSE(p.channels[2].color.has_value());
  ASSERT_EQ(p.tiff_data.size(), 2u);
  EXPECT_EQ(p.tiff_data[0].ifd, 3);
  EXPECT_EQ(p.tiff_data[0].first_z, 1);
  EXPECT_EQ(p.tiff_data[0].first_c, 2);
  EXPECT_EQ(p.tiff_data[0].first_t, 6);
  EXPECT_EQ(p.tiff_data[0].plane_count, 1);
  EXPECT_EQ(p.tiff_data[0].uuid, "urn:uuid:1234");
  EXPECT_EQ(p.tiff_data[0].file_name, "a.ome.tif");
  EXPECT_FALSE(p.tiff_data[1].ifd.has_value());
  EXPECT_FALSE(p.tiff_data[1].plane_count.has_value());
  EXPECT_EQ(p.tiff_data[1].first_z, 0);
  EXPECT_EQ(p.tiff_data[1].uuid, "");
  EXPECT_EQ(m.images[1].pixels.dimension_order, DimensionOrder::kXYTZC);
  EXPECT_EQ(m.images[1].pixels.type, DataType::kFloat64);
  EXPECT_FALSE(m.images[1].pixels.physical_size_um[0].has_value());
}

TEST(OmeXmlTest, AllDimensionOrdersRoundTrip) {
  for (const char* name : {"XYZCT", "XYZTC", "XYCTZ", "XYCZT", "XYTCZ", "XYTZC"}) {
    std::optional<DimensionOrder> order = DimensionOrderFromName(name);
    ASSERT_TRUE(order.has_value()) << name;
    EXPECT_EQ(DimensionOrderName(*order), name);
  }
  EXPECT_FALSE(DimensionOrderFromName("XYZ").has_value());
  EXPECT_FALSE(DimensionOrderFromName("xyzct").has_value());
  EXPECT_FALSE(DimensionOrderFromName("XYZZT").has_value());
}

TEST(OmeXmlTest, MatchesElementsIgnoringPrefixAndSchemaYear) {
  // 2012-06 with a prefix on every element.
  std::string xml =
      "<ome:OME xmlns:ome=\"http://www.openmicroscopy.org/Schemas/OME/2012-06\">"
      "<ome:Image ID=\"Image:0\"><ome:Pixels DimensionOrder=\"XYZTC\" Type=\"float\" SizeX=\"2\" "
      "SizeY=\"2\" SizeZ=\"1\" SizeC=\"2\" SizeT=\"1\"><ome:Channel Name=\"a\"/>"
      "<ome:Channel Name=\"b\"/><ome:TiffData IFD=\"1\"><ome:UUID FileName=\"f.tif\">u</ome:UUID>"
      "</ome:TiffData></ome:Pixels></ome:Image></ome:OME>";
  Result<OmeMetadata> parsed = ParseOmeXml(xml, "prefixed.xml");
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  ASSERT_EQ(parsed->images.size(), 1u);
  const OmePixels& p = parsed->images[0].pixels;
  EXPECT_EQ(p.type, DataType::kFloat32);
  ASSERT_EQ(p.channels.size(), 2u);
  EXPECT_EQ(p.channels[1].name, "b");
  ASSERT_EQ(p.tiff_data.size(), 1u);
  EXPECT_EQ(p.tiff_data[0].ifd, 1);
  EXPECT_EQ(p.tiff_data[0].file_name, "f.tif");
  EXPECT_EQ(p.tiff_data[0].uuid, "u");

  // 2008-02: PixelType instead of Type, LogicalChannel in the Image.
  std::string old_xml =
      "<OME xmlns=\"http://www.openmicroscopy.org/Schemas/OME/2008-02\"><Image ID=\"i\">"
      "<LogicalChannel Name=\"old\" SamplesPerPixel=\"1\"/>"
      "<Pixels DimensionOrder=\"XYZCT\" PixelType=\"uint8\" SizeX=\"2\" SizeY=\"2\" SizeZ=\"1\" "
      "SizeC=\"1\" SizeT=\"1\"><TiffData/></Pixels></Image></OME>";
  parsed = ParseOmeXml(old_xml, "old.ome.tif");
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  EXPECT_EQ(parsed->images[0].pixels.type, DataType::kUint8);
  ASSERT_EQ(parsed->images[0].pixels.channels.size(), 1u);
  EXPECT_EQ(parsed->images[0].pixels.channels[0].name, "old");
}

TEST(OmeXmlTest, ParsesBinaryOnly) {
  std::string xml =
      "<?xml version=\"1.0\"?><OME xmlns=\"http://www.openmicroscopy.org/Schemas/OME/2016-06\" "
      "UUID=\"urn:uuid:member\"><BinaryOnly MetadataFile=\"master.ome.tif\" "
      "UUID=\"urn:uuid:master\"/></OME>";
  Result<OmeMetadata> parsed = ParseOmeXml(xml, "member.ome.tif");
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  EXPECT_EQ(parsed->uuid, "urn:uuid:member");
  ASSERT_TRUE(parsed->binary_only.has_value());
  EXPECT_EQ(parsed->binary_only->metadata_file, "master.ome.tif");
  EXPECT_EQ(parsed->binary_only->uuid, "urn:uuid:master");
  EXPECT_TRUE(parsed->images.empty());
}

TEST(OmeXmlTest, ConvertsLengthUnits) {
  struct Case {
    const char* unit;
    double um;
  };
  for (Case c : {Case{"m", 1e6}, Case{"cm", 1e4}, Case{"mm", 1e3}, Case{"\xC2\xB5m", 1},
                 Case{"\xCE\xBCm", 1}, Case{"um", 1}, Case{"nm", 1e-3}, Case{"pm", 1e-6},
                 Case{"Ym", 1e30}, Case{"km", 1e9}, Case{"\xC3\x85", 1e-4},
                 Case{"\xE2\x84\xAB", 1e-4}, Case{"angstrom", 1e-4}, Case{"in", 25400}}) {
    std::optional<double> f = MicrometresPerLengthUnit(c.unit);
    ASSERT_TRUE(f.has_value()) << c.unit;
    EXPECT_DOUBLE_EQ(*f, c.um) << c.unit;
  }
  EXPECT_FALSE(MicrometresPerLengthUnit("s").has_value());
  EXPECT_FALSE(MicrometresPerLengthUnit("pixel").has_value());
  EXPECT_FALSE(MicrometresPerLengthUnit("").has_value());
  EXPECT_FALSE(MicrometresPerLengthUnit("M").has_value());

  // Through the parser: Ångström and nm, default µm.
  Result<OmeMetadata> parsed =
      ParseOmeXml(Doc(std::string(kSizes) + " PhysicalSizeX=\"2.5\" PhysicalSizeXUnit=\"\xC3\x85\" "
                                            "PhysicalSizeY=\"250\" PhysicalSizeYUnit=\"nm\" "
                                            "PhysicalSizeZ=\"3\" PhysicalSizeZUnit=\"\xC2\xB5m\""),
                  "u.ome.tif");
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  EXPECT_DOUBLE_EQ(*parsed->images[0].pixels.physical_size_um[0], 2.5e-4);
  EXPECT_DOUBLE_EQ(*parsed->images[0].pixels.physical_size_um[1], 0.25);
  EXPECT_DOUBLE_EQ(*parsed->images[0].pixels.physical_size_um[2], 3.0);

  // A time unit on a length is an error; "pixel" is no spacing; zero is no spacing.
  parsed = ParseOmeXml(Doc(std::string(kSizes) + " PhysicalSizeX=\"1\" PhysicalSizeXUnit=\"s\""),
                       "t.ome.tif");
  ASSERT_FALSE(parsed.ok());
  EXPECT_EQ(parsed.status().code(), StatusCode::kCorrupt);
  EXPECT_NE(parsed.status().message().find("t.ome.tif"), std::string::npos);
  EXPECT_NE(parsed.status().message().find("PhysicalSizeXUnit"), std::string::npos);
  parsed = ParseOmeXml(Doc(std::string(kSizes) + " PhysicalSizeX=\"1\" PhysicalSizeXUnit=\"pixel\" "
                                                 "PhysicalSizeY=\"0\""),
                       "p.ome.tif");
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  EXPECT_FALSE(parsed->images[0].pixels.physical_size_um[0].has_value());
  EXPECT_FALSE(parsed->images[0].pixels.physical_size_um[1].has_value());
  parsed = ParseOmeXml(Doc(std::string(kSizes) + " PhysicalSizeX=\"abc\""), "n.ome.tif");
  EXPECT_FALSE(parsed.ok());
}

TEST(OmeXmlTest, ParsesColors) {
  EXPECT_EQ(ParseOmeColor("-1"), (Rgba{255, 255, 255, 255}));
  EXPECT_EQ(ParseOmeColor("-2147483648"), (Rgba{128, 0, 0, 0}));
  EXPECT_EQ(ParseOmeColor("65535"), (Rgba{0, 0, 255, 255}));
  EXPECT_EQ(ParseOmeColor("4294967295"), (Rgba{255, 255, 255, 255}));  // Unsigned spelling.
  EXPECT_EQ(ParseOmeColor("305419896"), (Rgba{0x12, 0x34, 0x56, 0x78}));
  EXPECT_FALSE(ParseOmeColor("4294967296").has_value());
  EXPECT_FALSE(ParseOmeColor("-2147483649").has_value());
  EXPECT_FALSE(ParseOmeColor("red").has_value());
}

TEST(OmeXmlTest, SniffsOmeXml) {
  EXPECT_TRUE(LooksLikeOmeXml("<?xml version=\"1.0\"?><!-- <x> --><OME xmlns=\"a\"/>"));
  EXPECT_TRUE(LooksLikeOmeXml("  <ome:OME xmlns:ome=\"a\"></ome:OME>"));
  EXPECT_TRUE(LooksLikeOmeXml("<OME>"));
  EXPECT_FALSE(LooksLikeOmeXml("ImageJ=1.49h\nframes=10\n"));
  EXPECT_FALSE(LooksLikeOmeXml("<?xml version=\"1.0\"?><VolumeFile/>"));
  EXPECT_FALSE(LooksLikeOmeXml("<OMEX/>"));
  EXPECT_FALSE(LooksLikeOmeXml(""));
  EXPECT_FALSE(LooksLikeOmeXml("Stage:OMEGA-3 position 12"));
  // A damaged start (an unterminated prolog) still claims OME by its end or its namespace, so
  // that the document is parsed and its problem reported rather than silently ignored.
  EXPECT_TRUE(LooksLikeOmeXml("<?xml version=\"1.0\" <OME><Image/></OME>\n"));
  EXPECT_TRUE(
      LooksLikeOmeXml("<!-- unterminated <OME xmlns=\"http://www.openmicroscopy.org/"
                      "Schemas/OME/2016-06\">"));
}

// Each invalid document must be rejected with a message naming the file and the problem.
TEST(OmeXmlTest, RejectsInvalidDocuments) {
  struct Case {
    std::string xml;
    const char* expect_in_message;
  };
  const std::string ok_order = "DimensionOrder=\"XYZCT\" Type=\"uint8\" ";
  const std::vector<Case> cases = {
      {"<OME><Image", "malformed"},
      {"not xml at all", "malformed"},
      {"<Foo/>", "not OME"},
      {"<OME/>", "no Image"},
      {"<OME><Image ID=\"i\"/></OME>", "no Pixels"},
      {Doc("Type=\"uint8\" SizeX=\"1\" SizeY=\"1\" SizeZ=\"1\" SizeC=\"1\" SizeT=\"1\""),
       "DimensionOrder"},
      {Doc("DimensionOrder=\"XYZQT\" Type=\"uint8\" SizeX=\"1\" SizeY=\"1\" SizeZ=\"1\" "
           "SizeC=\"1\" SizeT=\"1\""),
       "XYZQT"},
      {Doc("DimensionOrder=\"XYZCT\" Type=\"int64\" SizeX=\"1\" SizeY=\"1\" SizeZ=\"1\" "
           "SizeC=\"1\" SizeT=\"1\""),
       "int64"},
      {Doc("DimensionOrder=\"XYZCT\" Type=\"bit\" SizeX=\"1\" SizeY=\"1\" SizeZ=\"1\" "
           "SizeC=\"1\" SizeT=\"1\""),
       "bit"},
      {Doc("DimensionOrder=\"XYZCT\" SizeX=\"1\" SizeY=\"1\" SizeZ=\"1\" SizeC=\"1\" "
           "SizeT=\"1\""),
       "Type is missing"},
      {Doc(ok_order + "SizeY=\"1\" SizeZ=\"1\" SizeC=\"1\" SizeT=\"1\""), "SizeX is missing"},
      {Doc(ok_order + "SizeX=\"0\" SizeY=\"1\" SizeZ=\"1\" SizeC=\"1\" SizeT=\"1\""), "SizeX"},
      {Doc(ok_order + "SizeX=\"1\" SizeY=\"-4\" SizeZ=\"1\" SizeC=\"1\" SizeT=\"1\""), "SizeY"},
      {Doc(ok_order + "SizeX=\"1\" SizeY=\"1\" SizeZ=\"1.5\" SizeC=\"1\" SizeT=\"1\""), "SizeZ"},
      {Doc(ok_order + "SizeX=\"1\" SizeY=\"1\" SizeZ=\"1\" SizeC=\"x\" SizeT=\"1\""), "SizeC"},
      {Doc(ok_order + "SizeX=\"1\" SizeY=\"1\" SizeZ=\"1\" SizeC=\"1\" SizeT=\"\""), "SizeT"},
      {Doc(ok_order + "SizeX=\"2147483649\" SizeY=\"1\" SizeZ=\"1\" SizeC=\"1\" SizeT=\"1\""),
       "more than 2^31"},
      {Doc(ok_order + "SizeX=\"99999999999999999999\" SizeY=\"1\" SizeZ=\"1\" SizeC=\"1\" "
                      "SizeT=\"1\""),
       "SizeX"},
      // Each size allowed on its own, but the product overflows 64 bits.
      {Doc(ok_order + "SizeX=\"2147483648\" SizeY=\"2147483648\" SizeZ=\"2147483648\" "
                      "SizeC=\"1\" SizeT=\"1\""),
       "overflow"},
      {Doc(std::string(kSizes), "<TiffData IFD=\"-1\"/>"), "IFD is negative"},
      {Doc(std::string(kSizes), "<TiffData FirstZ=\"-2\"/>"), "FirstZ is negative"},
      {Doc(std::string(kSizes), "<TiffData FirstC=\"-1\"/>"), "FirstC is negative"},
      {Doc(std::string(kSizes), "<TiffData FirstT=\"-1\"/>"), "FirstT is negative"},
      {Doc(std::string(kSizes), "<TiffData PlaneCount=\"-3\"/>"), "PlaneCount is negative"},
      {Doc(std::string(kSizes), "<TiffData IFD=\"one\"/>"), "IFD is not an integer"},
      {Doc(std::string(kSizes), "<TiffData FirstZ=\"2\"/>"), "outside the image"},
      {Doc(std::string(kSizes), "<Channel/><Channel/>"), "2 Channel elements"},
      {Doc(std::string(kSizes), "<Channel SamplesPerPixel=\"0\"/>"), "SamplesPerPixel"},
      {Doc(std::string(kSizes), "<Channel Color=\"blue\"/>"), "Color"},
      {"<OME><BinaryOnly UUID=\"x\"/></OME>", "MetadataFile"},
  };
  for (const Case& c : cases) {
    Result<OmeMetadata> parsed = ParseOmeXml(c.xml, "/data/bad.ome.tif");
    ASSERT_FALSE(parsed.ok()) << c.xml;
    EXPECT_EQ(parsed.status().code(), StatusCode::kCorrupt) << c.xml;
    EXPECT_NE(parsed.status().message().find("/data/bad.ome.tif"), std::string::npos)
        << parsed.status().message();
    EXPECT_NE(parsed.status().message().find(c.expect_in_message), std::string::npos)
        << "message: " << parsed.status().message() << "\nexpected: " << c.expect_in_message;
  }
}

TEST(OmeXmlTest, RejectsOversizedDocument) {
  std::string huge(kMaxOmeXmlBytes + 1, ' ');
  Result<OmeMetadata> parsed = ParseOmeXml(huge, "big.companion.ome");
  ASSERT_FALSE(parsed.ok());
  EXPECT_EQ(parsed.status().code(), StatusCode::kResourceExhausted);
  EXPECT_NE(parsed.status().message().find("big.companion.ome"), std::string::npos);
}

TEST(OmeXmlTest, ToleratesTrailingNuls) {
  std::string xml = Doc(kSizes);
  xml.append(3, '\0');
  Result<OmeMetadata> parsed = ParseOmeXml(xml, "nul.ome.tif");
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  EXPECT_EQ(parsed->images[0].pixels.size_x, 4);
}

}  // namespace
}  // namespace octoscope::io
