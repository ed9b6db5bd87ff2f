/*
 * forest_surface -- forest's leaf, bark and terrain material in RenderMan Shading Language (RI 3.2).
 *
 * The same model as forest's Mitsuba materials (forest.render.materials):
 *
 *   albedo   a  = basecolour * detail(s,t) * (Cs if tinted) * (f if bark)
 *                 detail = the texture's RGB, decoded from sRGB (1 without a texture),
 *                 Cs     = the tree's colour-map tint (the Color of its block in the instance file),
 *                 f      = the tree's bark factor, its user attribute "barktint" (hue/value jitter
 *                          and moss; 1 where the tree has none);
 *   opacity  Oi = Os * alpha(s,t)        the texture's fourth channel: the leaf-card mask;
 *   colour   Ci = Oi * a * (Ka*ambient() + Kd*((1-translucency)*diffuse(Nf) + translucency*diffuse(-Nf)))
 *                 translucency = the share of the light a leaf transmits (lit from behind).
 *
 * diffuse() carries no 1/pi: the export writes the sun's distantlight intensity as
 * irradiance/pi and the sky's ambientlight intensity as its radiance (forest.export.radiometry).
 *
 * Compile it with your renderer's shader compiler, from the export folder (prepare.sh does this):
 *   PRMan <= 21: shader forest_surface.sl      Aqsis: aqsl forest_surface.sl
 *   3Delight:    shaderdl forest_surface.sl    Pixie: sdrc forest_surface.sl
 */

surface forest_surface(
    color basecolour = 1;
    float tinted = 1;
    float bark = 0;
    string texturename = "";
    float translucency = 0;
    float Ka = 1;
    float Kd = 1)
{
    color albedo = basecolour;
    float alpha = 1;
    if (tinted != 0)
        albedo *= Cs;
    if (bark != 0) {
        color f = 1;
        if (attribute("user:barktint", f) == 0)
            f = 1;  /* the tree has no bark factor */
        albedo *= f;
    }
    if (texturename != "") {
        /* sRGB decoding (IEC 61966-2-1), channel by channel, written out: some compilers (aqsl 1.8)
           inline a user function called three times in one expression into a single result */
        color c = color texture(texturename, s, t);
        float r = comp(c, 0);
        float g = comp(c, 1);
        float b = comp(c, 2);
        if (r > 0.04045) r = pow((r + 0.055) / 1.055, 2.4); else r = r / 12.92;
        if (g > 0.04045) g = pow((g + 0.055) / 1.055, 2.4); else g = g / 12.92;
        if (b > 0.04045) b = pow((b + 0.055) / 1.055, 2.4); else b = b / 12.92;
        albedo *= color(r, g, b);
        alpha = float texture(texturename[3], s, t, "fill", 1);
    }
    normal Nf = faceforward(normalize(N), I);
    Oi = Os * alpha;
    Ci = Oi * albedo * (Ka * ambient() + Kd * ((1 - translucency) * diffuse(Nf) + translucency * diffuse(-Nf)));
}
